//! Table 5 (an obstacle the networks do not see), table 6 (clearance and
//! pairwise distances), the residual decay and the trajectory figures.

use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result};
use flowopt_methods::Method;
use flowopt_planner::problem::{Dim, Team};
use flowopt_planner::scenario::{RandomScenario, antipodal};

use super::figures::{self, BandCurve, BandPanel, Curve, PlanPanel};
use super::measures::{Band, PairwiseProfile, Series};
use super::report::{Table, ms, num, pct};
use super::rows::{DECAY_ITERATIONS, METHODS, OBSTACLES, PAIRWISE_INSTANTS, Row, Runs, plan_each, title};
use crate::offline::stats::{IterationStats, mean, quantile};

/// Table 5: an extra obstacle, unseen by the networks, at the safety filter.
pub(super) fn robustness(runs: &mut Runs, command: &str, dir: &Path, link: &str) -> Result<String> {
    let mut table = Table::new(&[
        "instances",
        "method",
        "success",
        "median ms",
        "to 0.01: mean (reached)",
        "to 0.001: mean (reached)",
    ]);
    // (obstacles, hidden, label): the generator draws obstacles one after
    // another, so the 8-obstacle instances are the 9-obstacle ones without
    // the last (tested in `flowopt_planner::scenario`).
    let cases = [
        (OBSTACLES, 0, format!("{OBSTACLES} obstacles, all seen")),
        (OBSTACLES + 1, 1, format!("{} obstacles, the last unseen by the networks", OBSTACLES + 1)),
        (OBSTACLES + 1, 0, format!("{} obstacles, all seen", OBSTACLES + 1)),
    ];
    let mut panels = Vec::new();
    for method in METHODS {
        let mut bands = Vec::new();
        for (c, (obstacles, hidden, label)) in cases.iter().enumerate() {
            if method == Method::Baseline && *hidden > 0 {
                continue;
            }
            let row = Row { hidden: *hidden, ..Row::new(Dim::Two, 16, *obstacles, method) };
            let lead = vec![label.to_string(), method.name().to_string()];
            let Some(records) = runs.for_table(row, &mut table, &lead)? else { continue };
            let coarse = IterationStats::of(records.iter().map(|r| r.iterations_to_0_01));
            let fine = IterationStats::of(records.iter().map(|r| r.iterations_to_0_001));
            let times: Vec<f64> = records.iter().map(|r| r.time_ms).collect();
            let mut cells = lead;
            cells.extend([
                pct(records.iter().filter(|r| r.success).count() as f64 / records.len() as f64),
                ms(quantile(&times, 0.5)),
                format!("{} ({})", num(coarse.mean, 1), pct(coarse.reached)),
                format!("{} ({})", num(fine.mean, 1), pct(fine.reached)),
            ]);
            table.row(cells);
            if method != Method::Baseline && (*hidden > 0 || *obstacles == OBSTACLES) {
                let histories: Vec<&[_]> = records.iter().map(|r| r.study.as_slice()).collect();
                bands.push(BandCurve {
                    label: label.to_string(),
                    colour: c + 3,
                    band: Band::of(&histories, Series::Primal, DECAY_ITERATIONS),
                });
            }
        }
        if !bands.is_empty() {
            panels.push(BandPanel {
                title: format!("{}: primal residual", method.name()),
                y_desc: "primal residual (m)".into(),
                bands,
            });
        }
    }
    let file = "robustness_residuals.svg";
    let figure = if panels.is_empty() {
        String::new()
    } else {
        figures::residual_bands(&dir.join(file), &panels, panels.len())?;
        format!("![primal residual with a hidden obstacle]({link}/{file})\n\n")
    };
    Ok(format!(
        "## 5. Robustness: an obstacle the networks do not see (16 robots, 2D)\n\n{}\nCommand: `{command}`. \
         The instances of table 3, then the same with one more static obstacle (the generator draws \
         obstacles one after another, so the first {} are the same), hidden from the flow policy and the \
         initialiser while the rerouting and the safety filter enforce it, then shown to everyone. Iterations: the residual \
         study of table 2 (the baseline from its cold start, the learned methods from the chosen candidate's \
         start).\n\n{figure}",
        table.render(),
        OBSTACLES
    ))
}

/// Table 6 and its figure: pairwise distances over time.
pub(super) fn clearance(runs: &mut Runs, command: &str, dir: &Path, link: &str) -> Result<String> {
    let mut table = Table::new(&[
        "team",
        "method",
        "mean pairwise distance (m)",
        "lowest over time of the mean (m)",
        "closest pair, mean / worst (m)",
    ]);
    let mut curves = Vec::new();
    let samples = PAIRWISE_INSTANTS;
    for (robots, shade) in [(8, 0), (16, 1), (32, 2)] {
        for (c, method) in METHODS.into_iter().enumerate() {
            let row = Row::new(Dim::Two, robots, 0, method);
            let lead = vec![row.label(), method.name().to_string()];
            let team = row.team();
            let Some(records) = runs.for_table(row, &mut table, &lead)? else { continue };
            let profiles: Vec<PairwiseProfile> =
                records.iter().filter(|r| r.success).map(|r| PairwiseProfile::of(&team, &r.xi, samples)).collect();
            let over_time: Vec<f64> =
                (0..samples).map(|k| mean(&profiles.iter().map(|p| p.mean[k]).collect::<Vec<_>>())).collect();
            let closest: Vec<f64> =
                profiles.iter().map(|p| p.min.iter().copied().fold(f64::INFINITY, f64::min)).collect();
            table.row(vec![
                lead[0].clone(),
                lead[1].clone(),
                num(mean(&over_time), 3),
                num(over_time.iter().copied().fold(f64::NAN, f64::min), 3),
                format!("{} / {}", num(mean(&closest), 3), num(closest.iter().copied().fold(f64::NAN, f64::min), 3)),
            ]);
            if shade == 1 {
                let horizon = team.horizon;
                curves.push(Curve {
                    label: format!("{} (16 robots)", method.name()),
                    colour: c,
                    points: over_time
                        .iter()
                        .enumerate()
                        .map(|(k, &d)| (horizon * k as f64 / (samples - 1) as f64, d))
                        .collect(),
                });
            }
        }
    }
    let file = "pairwise_distance.svg";
    let top = curves.iter().flat_map(|c| c.points.iter().map(|p| p.1)).fold(0.0, f64::max);
    figures::curves(
        &dir.join(file),
        "Mean pairwise distance over time: 16 robots, 2D",
        ("time (s)", "mean distance between robots (m)"),
        &curves,
        false,
        (0.0, 1.1 * top.max(0.1)),
    )?;
    Ok(format!(
        "## 6. Inter-robot clearance over time (2D, no obstacles)\n\n{}\nCommand: `{command}`. Centre-to-centre \
         distances on {PAIRWISE_INSTANTS} instants over the horizon, over the successful instances of table 1 (the separation \
         is {} m). Mean pairwise distance: over pairs, instants and instances.\n\n\
         ![mean pairwise distance over time]({link}/{file})\n\n",
        table.render(),
        Team::default_for(Dim::Two, 16).separation().0
    ))
}

/// The residual decay figure (primal and fixed point, 16 and 32 robots).
pub(super) fn residual_figure(runs: &mut Runs, dir: &Path, link: &str) -> Result<String> {
    let mut panels = Vec::new();
    for robots in [16, 32] {
        for (series, name) in [(Series::Primal, "primal"), (Series::FixedPoint, "fixed-point")] {
            let mut bands = Vec::new();
            for (c, method) in METHODS.into_iter().enumerate() {
                let row = Row::new(Dim::Two, robots, 0, method);
                if runs.unavailable(row).is_some() {
                    continue;
                }
                let histories: Vec<&[_]> = runs.get(row)?.iter().map(|r| r.study.as_slice()).collect();
                bands.push(BandCurve {
                    label: method.name().into(),
                    colour: c,
                    band: Band::of(&histories, series, DECAY_ITERATIONS),
                });
            }
            panels.push(BandPanel {
                title: format!("{robots} robots, 2D: {name} residual"),
                y_desc: format!("{name} residual"),
                bands,
            });
        }
    }
    let file = "residual_decay.svg";
    figures::residual_bands(&dir.join(file), &panels, 2)?;
    Ok(format!(
        "## Residual decay\n\nThe residual studies of table 2 (2D): mean (line) and 10th-90th percentile band \
         over the instances, per iteration; an instance whose study stopped (primal residual 0.001 reached) \
         keeps its last value.\n\n![residual decay]({link}/{file})\n\n"
    ))
}

/// Trajectory plots and the moving-obstacle snapshots.
pub(super) fn trajectory_figures(runs: &mut Runs, seed: u64, dir: &Path, link: &str) -> Result<String> {
    let team = Team::default_for(Dim::Two, 16);
    let circle = antipodal(&team, 0.9).context("building the antipodal swap")?;
    let obstacles = Row::new(Dim::Two, 16, OBSTACLES, Method::Baseline).instance(seed)?;
    let moving = RandomScenario::new(team.clone())
        .with_obstacles(4)
        .with_obstacle_speed(0.3)
        .generate(seed)
        .context("generating the moving-obstacle scene")?;
    let mut out = String::from("## Trajectories\n\n");
    let learned_ok = runs.unavailable(Row::new(Dim::Two, 16, 0, Method::Flowopt)).is_none();
    let methods: Vec<Method> =
        if learned_ok { vec![Method::Baseline, Method::Flowopt] } else { vec![Method::Baseline] };
    let scene = format!("random 16-robot scene with {OBSTACLES} static obstacles");
    for (problem, file, what) in [
        (&circle, "trajectories_antipodal.svg", "antipodal swap of 16 robots on a circle of radius 0.9 m"),
        (&obstacles, "trajectories_obstacles.svg", scene.as_str()),
    ] {
        let plans = plan_each(runs, problem, &methods, seed)?;
        let panels: Vec<PlanPanel> =
            plans.iter().map(|(m, r)| PlanPanel { title: title(*m, r), problem, xi: &r.xi }).collect();
        figures::trajectories(&dir.join(file), &panels)?;
        let _ = write!(out, "The {what} (seed {}):\n\n![{what}]({link}/{file})\n\n", seed);
    }
    let plans = plan_each(runs, &moving, &methods, seed)?;
    let panels: Vec<PlanPanel> =
        plans.iter().map(|(m, r)| PlanPanel { title: m.name().to_string(), problem: &moving, xi: &r.xi }).collect();
    let file = "moving_obstacles.svg";
    let instants: Vec<f64> = (0..5).map(|i| team.horizon * f64::from(i) / 4.0).collect();
    figures::snapshots(&dir.join(file), &panels, &instants)?;
    let details: Vec<String> = plans.iter().map(|(m, r)| title(*m, r)).collect();
    let _ = write!(
        out,
        "Snapshots of 16 robots crossing 4 obstacles moving at up to 0.3 m/s (seed {}; robots as discs of \
         their size, paths so far, obstacles where they are at that instant; the networks were trained on \
         static obstacles only, the safety filter enforces the moving ones). One row per method: {}.\n\n\
         ![moving obstacles]({link}/{file})\n\n\
         The trajectory panels' titles give the method, whether the plan passed the dense verdict, its \
         smoothness and its planning time. Starts are open discs of the robot's size, goals are crosses, \
         obstacles grey (moving ones with a 0.5 s velocity arrow).\n",
        seed,
        details.join("; ")
    );
    Ok(out)
}
