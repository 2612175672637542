//! The source layout's rules, checked on every crate of the workspace:
//! no two source files import each other in a circle (directly or through
//! others), and no source file has more than 600 lines before its tests.
//!
//! A file imports another when one of its `use` declarations or paths
//! (`crate::..`, `super::..`, `self::..`, or a child module's name) leads
//! into the other's module; comments and test code are not read.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Lines a source file may have before its `#[cfg(test)]` module.
const MAX_LINES: usize = 600;

/// The workspace's crates: their `src` directories.
fn crate_roots() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut roots = vec![root.join("src")];
    for entry in std::fs::read_dir(root).unwrap().flatten() {
        let src = entry.path().join("src");
        if entry.path().join("Cargo.toml").is_file() && src.is_dir() {
            roots.push(src);
        }
    }
    roots.sort();
    roots
}

/// Every `.rs` file under `dir`.
fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap().flatten() {
        let path = entry.path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The module path of `file` in the crate whose sources are under `src`.
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let relative = file.strip_prefix(src).unwrap().with_extension("");
    let mut parts: Vec<String> = relative.iter().map(|p| p.to_string_lossy().into_owned()).collect();
    if matches!(parts.last().map(String::as_str), Some("mod" | "lib" | "main")) {
        parts.pop();
    }
    // A binary's other roots (src/bin/x.rs) are crates of their own; none here.
    parts
}

/// The code of `text` before its tests, without comments or string contents.
fn code_before_tests(text: &str) -> String {
    let head = text.split("\n#[cfg(test)]").next().unwrap_or("");
    let mut out = String::with_capacity(head.len());
    for line in head.lines() {
        let mut in_string = false;
        let mut previous = ' ';
        for (i, c) in line.char_indices() {
            if !in_string && c == '/' && line[i..].starts_with("//") {
                break;
            }
            if c == '"' && previous != '\\' {
                in_string = !in_string;
            } else if !in_string {
                out.push(c);
            }
            previous = c;
        }
        out.push('\n');
    }
    out
}

/// The lines of `text` before its tests.
fn lines_before_tests(text: &str) -> usize {
    text.lines().take_while(|l| !l.starts_with("#[cfg(test)]")).count()
}

/// The child modules `code` declares (`mod x;`).
fn children(code: &str) -> BTreeSet<String> {
    code.lines()
        .filter_map(|l| {
            let l = l.trim();
            let l = l.strip_prefix("pub(crate) ").or_else(|| l.strip_prefix("pub ")).unwrap_or(l);
            l.strip_prefix("mod ")?.strip_suffix(';').map(|m| m.trim().to_string())
        })
        .collect()
}

/// Expands a `use` tree (`a::{b::c, d}`) into its paths.
fn expand(tree: &str, prefix: &str, out: &mut Vec<String>) {
    let tree = tree.trim();
    let Some(open) = tree.find('{') else {
        if !tree.is_empty() {
            out.push(format!("{prefix}{tree}"));
        }
        return;
    };
    let head = &tree[..open];
    let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    let (mut depth, mut start) = (0, 0);
    for (i, c) in inner.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                expand(&inner[start..i], &format!("{prefix}{head}"), out);
                start = i + 1;
            }
            _ => {}
        }
    }
    expand(&inner[start..], &format!("{prefix}{head}"), out);
}

/// Every path `code` names: its `use` declarations expanded, and the
/// `crate::`, `super::` and `self::` paths and those through a child module
/// it declares (`kid::f()`) in its expressions and types.
fn paths(code: &str) -> Vec<String> {
    let mut out = Vec::new();
    let flat = code.replace('\n', " ");
    let mut rest = flat.as_str();
    while let Some(at) = rest.find("use ") {
        let boundary = at == 0 || !rest[..at].ends_with(|c: char| c.is_alphanumeric() || c == '_');
        let after = &rest[at + 4..];
        let end = after.find(';').unwrap_or(after.len());
        if boundary {
            expand(&after[..end].replace(' ', ""), "", &mut out);
        }
        rest = &after[end..];
    }
    let kids: Vec<String> = children(code).into_iter().map(|k| format!("{k}::")).collect();
    let anchors = ["crate::", "super::", "self::"].into_iter().map(str::to_string).chain(kids);
    for anchor in anchors {
        let mut from = 0;
        while let Some(found) = flat[from..].find(anchor.as_str()) {
            let at = from + found;
            let before = &flat[..at];
            let boundary = !before.ends_with(|c: char| c.is_alphanumeric() || c == '_' || c == ':');
            if boundary {
                let path = flat[at..].chars().take_while(|c| c.is_alphanumeric() || *c == '_' || *c == ':');
                out.push(path.collect());
            }
            from = at + anchor.len();
        }
    }
    out
}

/// The module `path` (as written in module `at`, which declares `kids`)
/// leads into, or `None` for another crate's.
fn resolve(path: &str, at: &[String], kids: &BTreeSet<String>) -> Option<Vec<String>> {
    let mut segments = path.split("::").filter(|s| !s.is_empty()).map(str::to_string).peekable();
    let mut module: Vec<String> = match segments.peek().map(String::as_str) {
        Some("crate") => {
            segments.next();
            Vec::new()
        }
        Some("self") => {
            segments.next();
            at.to_vec()
        }
        Some("super") => at.to_vec(),
        Some(first) if kids.contains(first) => at.to_vec(),
        _ => return None,
    };
    for s in segments {
        if s == "super" {
            module.pop();
        } else {
            module.push(s);
        }
    }
    Some(module)
}

/// The files of the workspace's crates, and for each the files it imports.
fn import_graph() -> BTreeMap<PathBuf, BTreeSet<PathBuf>> {
    let mut graph = BTreeMap::new();
    for src in crate_roots() {
        let mut files = Vec::new();
        sources(&src, &mut files);
        let modules: BTreeMap<Vec<String>, PathBuf> = files.iter().map(|f| (module_of(&src, f), f.clone())).collect();
        for file in &files {
            let code = code_before_tests(&std::fs::read_to_string(file).unwrap());
            let at = module_of(&src, file);
            let kids = children(&code);
            let mut imports = BTreeSet::new();
            for path in paths(&code) {
                let Some(mut target) = resolve(&path, &at, &kids) else { continue };
                // The longest prefix that is a module of its own file.
                while !target.is_empty() && !modules.contains_key(&target) {
                    target.pop();
                }
                if let Some(to) = modules.get(&target).filter(|to| *to != file) {
                    imports.insert(to.clone());
                }
            }
            graph.insert(file.clone(), imports);
        }
    }
    graph
}

/// The import circles of `graph`: its strongly connected components of
/// more than one file.
fn circles(graph: &BTreeMap<PathBuf, BTreeSet<PathBuf>>) -> Vec<Vec<PathBuf>> {
    let reach = |from: &PathBuf| {
        let mut seen = BTreeSet::new();
        let mut stack = vec![from.clone()];
        while let Some(f) = stack.pop() {
            for to in graph.get(&f).into_iter().flatten() {
                if seen.insert(to.clone()) {
                    stack.push(to.clone());
                }
            }
        }
        seen
    };
    let reachable: BTreeMap<&PathBuf, BTreeSet<PathBuf>> = graph.keys().map(|f| (f, reach(f))).collect();
    let mut found: Vec<Vec<PathBuf>> = Vec::new();
    for (f, from_f) in &reachable {
        let circle: Vec<PathBuf> =
            from_f.iter().filter(|g| reachable.get(g).is_some_and(|from_g| from_g.contains(*f))).cloned().collect();
        if !circle.is_empty() && !found.iter().any(|c| c.contains(f)) {
            found.push(circle);
        }
    }
    found
}

#[test]
fn no_two_source_files_import_each_other_in_a_circle() {
    let graph = import_graph();
    assert!(graph.len() > 50, "the sources were found: {}", graph.len());
    let circles = circles(&graph);
    let shown: Vec<String> =
        circles.iter().map(|c| c.iter().map(|f| f.display().to_string()).collect::<Vec<_>>().join(" <-> ")).collect();
    assert!(circles.is_empty(), "import circles:\n{}", shown.join("\n"));
}

#[test]
fn no_source_file_is_over_600_lines_before_its_tests() {
    let mut long = Vec::new();
    for src in crate_roots() {
        let mut files = Vec::new();
        sources(&src, &mut files);
        for file in files {
            let lines = lines_before_tests(&std::fs::read_to_string(&file).unwrap());
            if lines > MAX_LINES {
                long.push(format!("{} ({lines})", file.display()));
            }
        }
    }
    assert!(long.is_empty(), "over {MAX_LINES} lines: {long:?}");
}

#[test]
fn the_checker_finds_a_circle_and_follows_use_trees() {
    let mut out = Vec::new();
    expand("super::{check::{Check,push},grid::SampleGrid}", "", &mut out);
    assert_eq!(out, ["super::check::Check", "super::check::push", "super::grid::SampleGrid"]);
    let at = vec!["am".to_string(), "run".to_string()];
    assert_eq!(resolve("super::pairs::X", &at, &BTreeSet::new()), Some(vec!["am".into(), "pairs".into(), "X".into()]));
    assert_eq!(resolve("nalgebra::Vector3", &at, &BTreeSet::new()), None);
    // A call through a child module is an import of the child.
    let code = "mod kid;\nfn f() { kid::g(); other::kid::h(); }";
    assert_eq!(paths(code), ["kid::g"]);
    assert_eq!(
        resolve("kid::g", &at, &children(code)),
        Some(vec!["am".into(), "run".into(), "kid".into(), "g".into()])
    );
    let file = |name: &str| PathBuf::from(name);
    let graph = BTreeMap::from([
        (file("a"), BTreeSet::from([file("b")])),
        (file("b"), BTreeSet::from([file("c")])),
        (file("c"), BTreeSet::from([file("a")])),
        (file("d"), BTreeSet::from([file("a")])),
    ]);
    assert_eq!(circles(&graph), vec![vec![file("a"), file("b"), file("c")]]);
}
