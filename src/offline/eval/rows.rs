//! The rows of the report: which instances a table row plans, the
//! records of each row (planned on first use), and the constants the
//! tables share.

use std::collections::HashMap;

use anyhow::{Context, Result};
use flowopt_methods::Method;
use flowopt_planner::problem::{Dim, Problem, Team};
use flowopt_planner::scenario::RandomScenario;
use flowopt_planner::scenes::{Family, Scene};
use indicatif::ProgressBar;

use super::report::Table;
use crate::offline::harness::{Harness, Record};

/// The methods compared, in table order; the index is the figure colour.
pub(super) const METHODS: [Method; 3] = [Method::Baseline, Method::Flowopt, Method::FlowNoInit];

/// Team sizes of the method comparison.
pub(super) const TEAMS: [(Dim, usize); 6] =
    [(Dim::Two, 8), (Dim::Two, 16), (Dim::Two, 32), (Dim::Three, 16), (Dim::Three, 32), (Dim::Three, 64)];

/// The paper's medians (ms, RTX 5090) for the teams of [`TEAMS`]: (Flow-Opt, from scratch).
pub(super) const PAPER_MS: [(f64, f64); 6] =
    [(51.5, 218.0), (65.4, 593.0), (297.0, 3407.0), (69.0, 148.0), (151.0, 999.0), (1020.0, 33700.0)];

/// Obstacles of the time-budget and robustness studies.
pub(super) const OBSTACLES: usize = 8;

/// Time budgets of the success-versus-time study (ms).
pub(super) const BUDGETS_MS: [f64; 12] = [0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 35.0, 50.0, 80.0, 120.0, 200.0, 500.0];

/// Instants of the pairwise-distance profiles (table 6).
pub(super) const PAIRWISE_INSTANTS: usize = 101;

/// Iterations shown in the residual decay figures.
pub(super) const DECAY_ITERATIONS: usize = 600;

/// One row of instances: a team, a generated obstacle count, how many of
/// them (the last ones) are hidden from the networks, and a method; the
/// benchmark's random instances, or a scene family's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub(super) struct Row {
    pub(super) dim: Dim,
    pub(super) robots: usize,
    pub(super) obstacles: usize,
    /// Obstacles the safety filter enforces but the networks do not see.
    pub(super) hidden: usize,
    pub(super) method: Method,
    /// The family of `flowopt_planner::scenes` generating the instances,
    /// planned without the residual study; `None`: the benchmark's
    /// [`RandomScenario`] instances, with the study.
    pub(super) family: Option<Family>,
    /// Most instances of the row (slow scenes); `None`: `--problems`.
    pub(super) cap: Option<u64>,
}

impl Row {
    pub(super) fn new(dim: Dim, robots: usize, obstacles: usize, method: Method) -> Self {
        Self { dim, robots, obstacles, hidden: 0, method, family: None, cap: None }
    }

    /// A row of `family`'s scenes (no obstacles beyond the family's own),
    /// at most `cap` instances.
    pub(super) fn scene(family: Family, dim: Dim, robots: usize, method: Method, cap: u64) -> Self {
        Self { family: Some(family), cap: Some(cap), ..Self::new(dim, robots, 0, method) }
    }

    /// The default team of the row's shape (a scene family grows its
    /// workspace with the team; dimension, robots and basis are these).
    pub(super) fn team(&self) -> Team {
        Team::default_for(self.dim, self.robots)
    }

    /// The team as the tables name it, e.g. `2D, 16`.
    pub(super) fn label(&self) -> String {
        format!("{}D, {}", self.dim.axes(), self.robots)
    }

    /// Instance `seed` of this row.
    pub(super) fn instance(&self, seed: u64) -> Result<Problem> {
        match self.family {
            None => RandomScenario::new(self.team())
                .with_obstacles(self.obstacles)
                .generate(seed)
                .with_context(|| format!("generating the instance with seed {seed}")),
            Some(family) => {
                let scene = Scene { obstacles: self.obstacles, ..Scene::new(family, self.dim, self.robots, seed) };
                let (problem, _) = scene
                    .generate()
                    .with_context(|| format!("generating the {} scene with seed {seed}", family.name()))?;
                Ok(problem)
            }
        }
    }

    /// Instances of the row when a row has `problems` by default.
    pub(super) fn count(&self, problems: u64) -> u64 {
        self.cap.map_or(problems, |cap| cap.min(problems))
    }
}

/// Records per row, computed on first use.
pub(super) struct Runs {
    pub(super) planner: Harness,
    /// The planner of the scene-family rows: no residual study (its
    /// 10,000 untimed iterations per instance dominate on big teams).
    pub(super) scenes: Harness,
    pub(super) problems: u64,
    pub(super) seed: u64,
    pub(super) records: HashMap<Row, Vec<Record>>,
    /// Why a row could not be planned (scene-family rows, see
    /// [`Runs::for_scene_table`]).
    pub(super) failed: HashMap<Row, String>,
    pub(super) progress: ProgressBar,
    /// Why the learned methods cannot plan a team shape, per dimension.
    pub(super) unavailable: HashMap<Dim, Option<String>>,
}

impl Runs {
    /// Why `row`'s method cannot plan its team, if it cannot.
    pub(super) fn unavailable(&mut self, row: Row) -> Option<String> {
        if row.method == Method::Baseline {
            return None;
        }
        if !self.unavailable.contains_key(&row.dim) {
            let reason = self.planner.learned_unavailable(&row.team());
            self.unavailable.insert(row.dim, reason);
        }
        self.unavailable[&row.dim].clone()
    }

    /// The records of `row` for a table row led by `lead`; when the
    /// row's method cannot plan its team, `None`, and the table gets a row
    /// saying why.
    pub(super) fn for_table(&mut self, row: Row, table: &mut Table, lead: &[String]) -> Result<Option<&[Record]>> {
        if let Some(reason) = self.unavailable(row) {
            table.unavailable(lead, &reason);
            return Ok(None);
        }
        self.get(row).map(Some)
    }

    /// [`Runs::for_table`] for the scene-family rows, where a row that
    /// cannot be planned (an error while generating or planning an
    /// instance) gets a table row saying so and the report goes on.
    pub(super) fn for_scene_table(&mut self, row: Row, table: &mut Table, lead: &[String]) -> Option<&[Record]> {
        if let Some(reason) = self.unavailable(row) {
            table.unavailable(lead, &reason);
            return None;
        }
        if !self.failed.contains_key(&row)
            && let Some(error) = self.get(row).err()
        {
            self.failed.insert(row, format!("{error:#}"));
        }
        if let Some(error) = self.failed.get(&row) {
            let mut cells = lead.to_vec();
            cells.push(format!("failed: {error}"));
            table.row(cells);
            return None;
        }
        self.records.get(&row).map(Vec::as_slice)
    }

    /// The records of `row`, planning its instances the first time.
    pub(super) fn get(&mut self, row: Row) -> Result<&[Record]> {
        if !self.records.contains_key(&row) {
            self.progress.set_message(format!(
                "{:?} {}D {} robots {} obstacles ({} hidden){}",
                row.method,
                row.dim.axes(),
                row.robots,
                row.obstacles,
                row.hidden,
                row.family.map_or(String::new(), |f| format!(" {} scenes", f.name()))
            ));
            let count = row.count(self.problems);
            self.progress.inc_length(count);
            let planner = if row.family.is_some() { &mut self.scenes } else { &mut self.planner };
            let mut records = Vec::with_capacity(count as usize);
            for i in 0..count {
                let seed = self.seed + i;
                let problem = row.instance(seed)?;
                records.push(planner.run_hiding(row.method, &problem, row.hidden, seed)?);
                self.progress.inc(1);
            }
            self.records.insert(row, records);
        }
        Ok(&self.records[&row])
    }
}

/// Plans `problem` with every method (noise seed `seed`).
pub(super) fn plan_each(
    runs: &mut Runs,
    problem: &Problem,
    methods: &[Method],
    seed: u64,
) -> Result<Vec<(Method, Record)>> {
    methods.iter().map(|&m| Ok((m, runs.planner.run(m, problem, seed)?))).collect()
}

pub(super) fn title(method: Method, r: &Record) -> String {
    format!(
        "{}: {}, smoothness {:.2}, {:.1} ms",
        method.name(),
        if r.success { "verified" } else { "NOT verified" },
        r.smoothness,
        r.time_ms
    )
}
