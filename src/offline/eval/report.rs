//! Markdown pieces of the evaluation report: tables and number formats.

/// A markdown table built row by row.
#[derive(Debug, Clone, PartialEq)]
pub struct Table {
    header: Vec<String>,
    rows: Vec<Vec<String>>,
}

impl Table {
    /// A table with these column headings.
    pub fn new(header: &[&str]) -> Self {
        Self { header: header.iter().map(|h| h.to_string()).collect(), rows: Vec::new() }
    }

    /// Appends a row; missing cells are left empty, extra cells dropped.
    pub fn row(&mut self, mut cells: Vec<String>) {
        cells.resize(self.header.len(), String::new());
        self.rows.push(cells);
    }

    /// Appends a row whose first cells are `lead`, then one cell saying why
    /// there is no figure (`reason`); the remaining cells stay empty.
    pub fn unavailable(&mut self, lead: &[String], reason: &str) {
        let mut cells = lead.to_vec();
        cells.push(format!("not yet available: {reason}"));
        self.row(cells);
    }

    /// The table as GitHub-flavoured markdown (pipes in cells escaped).
    pub fn render(&self) -> String {
        let line = |cells: &[String]| {
            let cells: Vec<String> = cells.iter().map(|c| c.replace('|', "\\|")).collect();
            format!("| {} |\n", cells.join(" | "))
        };
        let mut out = line(&self.header);
        out.push_str(&line(&vec!["---".to_string(); self.header.len()]));
        for r in &self.rows {
            out.push_str(&line(r));
        }
        out
    }
}

/// A time in milliseconds with precision suited to its size.
pub fn ms(v: f64) -> String {
    if !v.is_finite() {
        "-".into()
    } else if v < 1.0 {
        format!("{v:.3}")
    } else if v < 100.0 {
        format!("{v:.2}")
    } else {
        format!("{v:.0}")
    }
}

/// A fraction as a percentage: whole when it is one, else one decimal
/// rounded down (99.95% must not read as 100%).
pub fn pct(v: f64) -> String {
    let p = 100.0 * v;
    if !p.is_finite() {
        "-".into()
    } else if (p - p.round()).abs() < 1e-9 {
        format!("{:.0}%", p.round())
    } else {
        format!("{:.1}%", (10.0 * p).floor() / 10.0)
    }
}

/// A number with `digits` decimals, or `-` when undefined.
pub fn num(v: f64, digits: usize) -> String {
    if v.is_finite() { format!("{v:.digits$}") } else { "-".into() }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_render_as_markdown_with_padding_and_escapes() {
        let mut t = Table::new(&["method", "a", "b"]);
        t.row(vec!["x|y".into(), "1".into()]);
        t.unavailable(&["flowopt".into()], "no 3D weights");
        assert_eq!(
            t.render(),
            "| method | a | b |\n| --- | --- | --- |\n| x\\|y | 1 |  |\n| flowopt | not yet available: no 3D weights |  |\n"
        );
    }

    #[test]
    fn numbers_format_by_size_and_undefined_values_show_a_dash() {
        assert_eq!(ms(0.1234), "0.123");
        assert_eq!(ms(12.345), "12.35");
        assert_eq!(ms(1234.5), "1234");
        assert_eq!(ms(f64::NAN), "-");
        assert_eq!(pct(0.9995), "99.9%", "a failure never reads as 100%");
        assert_eq!(pct(2.0 / 3.0), "66.6%");
        assert_eq!(pct(0.98), "98%");
        assert_eq!(pct(1.0), "100%");
        assert_eq!(num(f64::NAN, 2), "-");
        assert_eq!(num(2.0, 1), "2.0");
    }
}
