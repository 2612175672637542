//! Tables 7 and 8 of the evaluation report: the methods on the scene
//! families of `flowopt_planner::scenes`, and the baseline's planning time
//! against the team size on the crowd scenes (with its figure). These rows
//! are planned without the residual study (see [`Runs`]).

use std::path::Path;

use anyhow::Result;
use flowopt_planner::problem::Dim;
use flowopt_planner::scenes::Family;

use super::figures::{self, Curve};
use super::report::{Table, ms, num, pct};
use super::rows::{Row, Runs};
use flowopt_methods::Method;

use crate::offline::harness::Record;
use crate::offline::stats::{mean, quantile};

/// The scene-family rows of table 7: family and robots (2D).
const FAMILY_ROWS: [(Family, usize); 11] = [
    (Family::Swap, 16),
    (Family::Swap, 32),
    (Family::Swap, 64),
    (Family::Crossing, 16),
    (Family::Crowd, 16),
    (Family::Crowd, 64),
    (Family::ObstacleField, 16),
    (Family::Formation, 16),
    (Family::Doorway, 16),
    (Family::Aisles, 16),
    (Family::PillarForest, 16),
];

/// The methods of table 7, in table order.
const FAMILY_METHODS: [Method; 3] = [Method::Auto, Method::Baseline, Method::Flowopt];

/// Most instances of a scene-family row (these scenes are slower).
const SCENE_CAP: u64 = 10;

/// Team sizes of the scaling study (crowd, 2D) and the most instances of
/// each.
const SCALING: [(usize, u64); 5] = [(16, SCENE_CAP), (32, SCENE_CAP), (64, SCENE_CAP), (128, 3), (256, 2)];

/// Largest team of the scaling study planned by [`Method::Auto`] too.
const SCALING_AUTO_UP_TO: usize = 64;

/// Figure colour of [`Method::Auto`] (the other methods keep the index of
/// their place in `super::METHODS`).
const AUTO_COLOUR: usize = 4;

/// The fraction of `records` that succeeded.
fn success(records: &[Record]) -> f64 {
    records.iter().filter(|r| r.success).count() as f64 / records.len() as f64
}

/// Median wall time (ms) of `records`.
fn median_ms(records: &[Record]) -> f64 {
    quantile(&records.iter().map(|r| r.time_ms).collect::<Vec<_>>(), 0.5)
}

/// Median over `records` of the time of one iteration (ms): each
/// instance's planning time divided by its iterations (instances with
/// none left out).
fn per_iteration_ms(records: &[Record]) -> f64 {
    let costs: Vec<f64> =
        records.iter().filter(|r| r.iterations > 0).map(|r| r.time_ms / r.iterations as f64).collect();
    quantile(&costs, 0.5)
}

/// Table 7: the methods on each scene family.
pub(super) fn family_table(runs: &mut Runs, command: &str) -> Result<String> {
    let mut table = Table::new(&[
        "family",
        "robots",
        "method",
        "success",
        "median ms",
        "p95 ms",
        "smoothness",
        "iterations (mean)",
    ]);
    for (family, robots) in FAMILY_ROWS {
        for method in FAMILY_METHODS {
            let row = Row::scene(family, Dim::Two, robots, method, SCENE_CAP);
            let lead = vec![family.name().to_string(), robots.to_string(), method.name().to_string()];
            let Some(records) = runs.for_scene_table(row, &mut table, &lead) else { continue };
            let times: Vec<f64> = records.iter().map(|r| r.time_ms).collect();
            let smoothness: Vec<f64> = records.iter().filter(|r| r.success).map(|r| r.smoothness).collect();
            let iterations: Vec<f64> = records.iter().map(|r| r.iterations as f64).collect();
            let mut cells = lead;
            cells.extend([
                pct(success(records)),
                ms(quantile(&times, 0.5)),
                ms(quantile(&times, 0.95)),
                num(mean(&smoothness), 2),
                num(mean(&iterations), 1),
            ]);
            table.row(cells);
        }
    }
    let count = runs.problems.min(SCENE_CAP);
    Ok(format!(
        "\n## 7. Scene families (2D)\n\n{}\nCommand: `{command}`. The scenes of `flowopt_planner::scenes` \
         (`Scene::new(family, Dim::Two, robots, seed)`: no random obstacles, every robot starting at rest), \
         the workspace grown with the team to keep the 16-robot benchmark's density: **swap** the antipodal \
         swap on a circle rotated by the seed, **crossing** two groups crossing at right angles in the middle, \
         **crowd** uniform random starts and goals, **obstacle-field** two groups in counterflow through a \
         field of pillars, **formation** from a grid to a ring, and the clutter families, passages of 1.5-2.5 \
         robot diameters between obstacle surfaces: **doorway** two rooms swapping through one or two doors, \
         **aisles** robots from one warehouse aisle to another, **pillar-forest** pillars over the whole \
         workspace. Instances per row: {count} (seeds {}..{}; at \
         most {SCENE_CAP}, these scenes are slower), planned one at a time without the residual study. \
         **auto** races the baseline and the learned pipeline (refining on one thread) on two threads, the \
         first verified plan winning, for teams of up to 32 robots (above, the baseline plans alone); its \
         time is the winner's. Smoothness is over the successful instances, \
         times and iterations over all; iterations are those of the returned plan's timed run (the baseline: \
         all its restarts together; a learned plan: the chosen candidate's safety filter).\n\n",
        table.render(),
        runs.seed,
        runs.seed + count,
    ))
}

/// Table 8 and its figure: the baseline (and auto on the smaller teams)
/// on crowd scenes of growing teams.
pub(super) fn scaling(runs: &mut Runs, command: &str, dir: &Path, link: &str) -> Result<String> {
    let mut table = Table::new(&[
        "robots",
        "method",
        "instances",
        "success",
        "median ms",
        "median iterations",
        "ms per iteration (median)",
    ]);
    let mut curves = Vec::new();
    for (method, colour) in [(Method::Baseline, 0), (Method::Auto, AUTO_COLOUR)] {
        let mut points = Vec::new();
        for (robots, cap) in SCALING {
            if method == Method::Auto && robots > SCALING_AUTO_UP_TO {
                continue;
            }
            let row = Row::scene(Family::Crowd, Dim::Two, robots, method, cap);
            let lead = vec![robots.to_string(), method.name().to_string(), row.count(runs.problems).to_string()];
            let Some(records) = runs.for_scene_table(row, &mut table, &lead) else { continue };
            let median = median_ms(records);
            let (iterations, per_iteration) = if method == Method::Baseline {
                let iterations: Vec<f64> = records.iter().map(|r| r.iterations as f64).collect();
                (num(quantile(&iterations, 0.5), 0), ms(per_iteration_ms(records)))
            } else {
                ("-".to_string(), "-".to_string())
            };
            let mut cells = lead;
            cells.extend([pct(success(records)), ms(median), iterations, per_iteration]);
            table.row(cells);
            if median.is_finite() && median > 0.0 {
                points.push((robots as f64, median));
            }
        }
        if !points.is_empty() {
            curves.push(Curve { label: method.name().into(), colour, points });
        }
    }
    let file = "scaling_crowd.svg";
    let figure = if curves.is_empty() {
        String::new()
    } else {
        figures::log_log(
            &dir.join(file),
            "Median planning time against team size: crowd scenes, 2D",
            ("robots (log scale)", "median planning time (ms, log scale)"),
            &curves,
        )?;
        format!("![median planning time against team size]({link}/{file})\n\n")
    };
    let below: Vec<String> = SCALING.iter().filter(|s| s.1 == SCENE_CAP).map(|s| s.0.to_string()).collect();
    let above: Vec<String> =
        SCALING.iter().filter(|s| s.1 != SCENE_CAP).map(|s| format!("{} at {} robots", s.1, s.0)).collect();
    Ok(format!(
        "## 8. Planning time against team size (crowd scenes, 2D)\n\n{}\nCommand: `{command}`. The crowd \
         scenes of table 7 (uniform random starts and goals, the workspace grown to keep the 16-robot \
         benchmark's density) at {} robots, planned by the baseline and, up to {SCALING_AUTO_UP_TO} robots, by \
         auto, one at a time without the residual study, seeds from {}: at most {SCENE_CAP} instances per row \
         at {} robots, {} (fewer when `--problems` is smaller). Times are wall-clock over all instances; \
         iterations are the baseline's, all restarts together; ms per iteration is the median over the \
         instances of the planning time (preparation and verification included) divided by the iterations. \
         Auto's iterations are those of whichever planner won, so its iteration columns are empty. A row \
         whose instances could not be planned says why. The figure plots the median times on log-log \
         axes.\n\n{figure}",
        table.render(),
        SCALING.iter().map(|s| s.0.to_string()).collect::<Vec<_>>().join(", "),
        runs.seed,
        below.join(", "),
        above.join(" and "),
    ))
}
