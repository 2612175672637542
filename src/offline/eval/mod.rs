//! `flowopt eval`: the evaluation report. Runs the from-scratch optimiser
//! and the learned pipeline (with and without the SF initialiser) on the
//! same seeded test instances (seeds from `--seed`, never used for
//! training), in one process, one instance at a time, and writes
//! `docs/RESULTS.md` with eight tables and SVG figures under `docs/figures/`:
//! six on the benchmark's random instances, then the scene families and
//! the baseline's scaling with the team size ([`families`]). Rows a method
//! cannot produce (no weights for the team) say so instead of showing a
//! number.

mod families;
mod figures;
mod measures;
mod report;

use std::collections::HashMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result};
use clap::Args;
use flowopt_models::pipeline::Settle;
use flowopt_planner::am::AmSettings;
use flowopt_planner::problem::{Dim, Problem, Team};
use flowopt_planner::scenario::{RandomScenario, antipodal};
use flowopt_planner::scenes::{Family, Scene};
use flowopt_planner::working_point::WorkingPoint;
use indicatif::{ProgressBar, ProgressStyle};

use crate::offline::methods::{LearnedArgs, Method, Overrides, Planner, Record};
use crate::offline::stats::{IterationStats, mean, quantile};
use figures::{BandCurve, BandPanel, Curve, PlanPanel};
use measures::{Band, PairwiseProfile, Series, success_within};
use report::{Table, ms, num, pct};

/// Write the evaluation report: tables and figures comparing the methods.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Fewer instances per row (20 instead of 100) and one throughput
    /// batch: the whole report in minutes.
    #[arg(long)]
    quick: bool,
    /// Instances per row (overrides the count `--quick` chooses).
    #[arg(long, value_parser = clap::value_parser!(u64).range(1..))]
    problems: Option<u64>,
    /// First instance seed; instance i uses seed + i.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// The report to write.
    #[arg(long, default_value = "docs/RESULTS.md")]
    out: PathBuf,
    /// Directory of the figures (linked relative to the report when under
    /// its directory, else by absolute path).
    #[arg(long, default_value = "docs/figures")]
    figures: PathBuf,
    #[command(flatten)]
    learned: LearnedArgs,
}

/// The methods compared, in table order; the index is the figure colour.
const METHODS: [Method; 3] = [Method::Baseline, Method::Flowopt, Method::FlowNoInit];

/// Team sizes of the method comparison.
const TEAMS: [(Dim, usize); 6] =
    [(Dim::Two, 8), (Dim::Two, 16), (Dim::Two, 32), (Dim::Three, 16), (Dim::Three, 32), (Dim::Three, 64)];

/// The paper's medians (ms, RTX 5090) for the teams of [`TEAMS`]: (Flow-Opt, from scratch).
const PAPER_MS: [(f64, f64); 6] =
    [(51.5, 218.0), (65.4, 593.0), (297.0, 3407.0), (69.0, 148.0), (151.0, 999.0), (1020.0, 33700.0)];

/// Obstacles of the time-budget and robustness studies.
const OBSTACLES: usize = 8;

/// Time budgets of the success-versus-time study (ms).
const BUDGETS_MS: [f64; 12] = [0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 35.0, 50.0, 80.0, 120.0, 200.0, 500.0];

/// docs/BENCHMARKS.md's criterion time of one 16-robot 2D safety-filter
/// iteration (µs), the reference of the report's machine-speed line.
const BENCHMARKS_SF_ITERATION_US: f64 = 12.75;

/// Instants of the pairwise-distance profiles (table 6).
const PAIRWISE_INSTANTS: usize = 101;

/// Iterations shown in the residual decay figures.
const DECAY_ITERATIONS: usize = 600;

/// One row of instances: a team, a generated obstacle count, how many of
/// them (the last ones) are hidden from the networks, and a method; the
/// benchmark's random instances, or a scene family's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
struct Row {
    dim: Dim,
    robots: usize,
    obstacles: usize,
    /// Obstacles the safety filter enforces but the networks do not see.
    hidden: usize,
    method: Method,
    /// The family of `flowopt_planner::scenes` generating the instances,
    /// planned without the residual study; `None`: the benchmark's
    /// [`RandomScenario`] instances, with the study.
    family: Option<Family>,
    /// Most instances of the row (slow scenes); `None`: `--problems`.
    cap: Option<u64>,
}

impl Row {
    fn new(dim: Dim, robots: usize, obstacles: usize, method: Method) -> Self {
        Self { dim, robots, obstacles, hidden: 0, method, family: None, cap: None }
    }

    /// A row of `family`'s scenes (no obstacles beyond the family's own),
    /// at most `cap` instances.
    fn scene(family: Family, dim: Dim, robots: usize, method: Method, cap: u64) -> Self {
        Self { family: Some(family), cap: Some(cap), ..Self::new(dim, robots, 0, method) }
    }

    /// The default team of the row's shape (a scene family grows its
    /// workspace with the team; dimension, robots and basis are these).
    fn team(&self) -> Team {
        Team::default_for(self.dim, self.robots)
    }

    /// The team as the tables name it, e.g. `2D, 16`.
    fn label(&self) -> String {
        format!("{}D, {}", self.dim.axes(), self.robots)
    }

    /// Instance `seed` of this row.
    fn instance(&self, seed: u64) -> Result<Problem> {
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
    fn count(&self, problems: u64) -> u64 {
        self.cap.map_or(problems, |cap| cap.min(problems))
    }
}

/// Records per row, computed on first use.
struct Runs {
    planner: Planner,
    /// The planner of the scene-family rows: no residual study (its
    /// 10,000 untimed iterations per instance dominate on big teams).
    scenes: Planner,
    problems: u64,
    seed: u64,
    records: HashMap<Row, Vec<Record>>,
    /// Why a row could not be planned (scene-family rows, see
    /// [`Runs::for_scene_table`]).
    failed: HashMap<Row, String>,
    progress: ProgressBar,
    /// Why the learned methods cannot plan a team shape, per dimension.
    unavailable: HashMap<Dim, Option<String>>,
}

impl Runs {
    /// Why `row`'s method cannot plan its team, if it cannot.
    fn unavailable(&mut self, row: Row) -> Option<String> {
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
    fn for_table(&mut self, row: Row, table: &mut Table, lead: &[String]) -> Result<Option<&[Record]>> {
        if let Some(reason) = self.unavailable(row) {
            table.unavailable(lead, &reason);
            return Ok(None);
        }
        self.get(row).map(Some)
    }

    /// [`Runs::for_table`] for the scene-family rows, where a row that
    /// cannot be planned (an error while generating or planning an
    /// instance) gets a table row saying so and the report goes on.
    fn for_scene_table(&mut self, row: Row, table: &mut Table, lead: &[String]) -> Option<&[Record]> {
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
    fn get(&mut self, row: Row) -> Result<&[Record]> {
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

/// Runs `flowopt eval`.
pub fn run(args: EvalArgs) -> Result<()> {
    let started = Instant::now();
    let problems = args.problems.unwrap_or(if args.quick { 20 } else { 100 });
    std::fs::create_dir_all(&args.figures).with_context(|| format!("creating {}", args.figures.display()))?;
    let progress = ProgressBar::new(0);
    progress.set_style(ProgressStyle::with_template("{bar:40} {pos}/{len} {msg} [{elapsed_precise}]")?);
    let mut runs = Runs {
        planner: Planner::new(Overrides::default(), Some(args.learned.clone())),
        scenes: Planner::new(Overrides { no_study: true, ..Overrides::default() }, Some(args.learned.clone())),
        problems,
        seed: args.seed,
        records: HashMap::new(),
        failed: HashMap::new(),
        progress,
        unavailable: HashMap::new(),
    };
    let command = if args.quick { "flowopt eval --quick".to_string() } else { "flowopt eval".to_string() };
    let mut doc = String::new();
    let figures = relative_figures(&args.out, &args.figures)?;

    doc.push_str(&method_comparison(&mut runs, &command)?);
    doc.push_str(&iterations(&mut runs, &command)?);
    doc.push_str(&success_versus_time(&mut runs, &command, &args.figures, &figures)?);
    doc.push_str(&throughput(&args, &command)?);
    doc.push_str(&robustness(&mut runs, &command, &args.figures, &figures)?);
    doc.push_str(&clearance(&mut runs, &command, &args.figures, &figures)?);
    doc.push_str(&residual_figure(&mut runs, &args.figures, &figures)?);
    doc.push_str(&trajectory_figures(&mut runs, &args, &figures)?);
    doc.push_str(&families::family_table(&mut runs, &command)?);
    doc.push_str(&families::scaling(&mut runs, &command, &args.figures, &figures)?);
    runs.progress.finish_and_clear();

    let header = header(&HeaderFacts {
        command: &command,
        problems,
        seed: args.seed,
        seconds: started.elapsed().as_secs_f64(),
        calibration_us: calibration_us()?,
        learned: &args.learned,
    });
    let text = header + &doc;
    std::fs::write(&args.out, text).with_context(|| format!("writing {}", args.out.display()))?;
    println!(
        "wrote {} and the figures in {} in {:.0} s",
        args.out.display(),
        args.figures.display(),
        started.elapsed().as_secs_f64()
    );
    Ok(())
}

/// The figures directory as the report links it: relative to the report
/// when under its directory, else absolute.
fn relative_figures(report: &Path, figures: &Path) -> Result<String> {
    let base = report.parent().unwrap_or(Path::new(""));
    match figures.strip_prefix(base) {
        Ok(relative) => Ok(relative.display().to_string()),
        Err(_) => Ok(std::path::absolute(figures)
            .with_context(|| format!("resolving {}", figures.display()))?
            .display()
            .to_string()),
    }
}

/// Median time (µs) of one safety-filter iteration at the criterion
/// benchmark's working point ([`WorkingPoint`], 16 robots, 2D), measured in
/// this run so that runs on machines of different speed can be compared.
fn calibration_us() -> Result<f64> {
    const ITERATIONS: usize = 500;
    let point = WorkingPoint::new(16, Dim::Two)?;
    let mut stepper = point.filter.stepper();
    let mut batches = Vec::new();
    for _ in 0..7 {
        // Every timed iteration starts from the working point's iterate.
        let mut states = vec![point.start.clone(); ITERATIONS];
        let began = Instant::now();
        for state in &mut states {
            std::hint::black_box(stepper.step(&point.prepared, state, 0));
        }
        batches.push(began.elapsed().as_secs_f64() * 1e6 / ITERATIONS as f64);
    }
    Ok(quantile(&batches, 0.5))
}

/// Cores and vector extension of this machine, as the report states them.
fn machine() -> String {
    let cores = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get);
    #[cfg(target_arch = "x86_64")]
    let avx2 = std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    let avx2 = false;
    format!("{cores} cores{}", if avx2 { " (AVX2)" } else { "" })
}

/// What the report says of its run and its methods.
struct HeaderFacts<'a> {
    command: &'a str,
    problems: u64,
    seed: u64,
    seconds: f64,
    calibration_us: f64,
    learned: &'a LearnedArgs,
}

fn header(f: &HeaderFacts) -> String {
    let optimiser = AmSettings::optimiser();
    let pipeline = f.learned.settings(Method::Flowopt);
    let settle = match pipeline.settle {
        Settle::FirstVerified => {
            "taking the candidates in rank order and returning the best-ranked one that verifies (the candidates \
             are sampled on the filter's threads)"
        }
        Settle::Smoothest => "returning the verified plan with the lowest smoothness",
    };
    let filter = AmSettings::safety_filter();
    let reroute = if pipeline.reroute {
        "robots a sample leaves inside a static obstacle rerouted around the obstacles (`am::Rerouter`), "
    } else {
        ""
    };
    let metric = if f.learned.sf_smoothing > 0.0 {
        format!(
            "in the smoothness-weighted metric with weight {} (`Objective::SmoothProjection`, docs/LEARNED.md)",
            f.learned.sf_smoothing
        )
    } else {
        "as the plain projection".to_string()
    };
    let init = if pipeline.init_without_obstacles {
        "the SF initialiser"
    } else {
        "the SF initialiser where there are obstacles (without them the filter starts from the samples, so \
         there `flowopt` and `flow-no-init` plan alike: docs/LEARNED.md, \"The initialiser where it can \
         matter\"; `flowopt eval --init-without-obstacles` gives the paper's ablation there)"
    };
    format!(
        "# Results\n\n\
         Written by `{}` (release build) on {}, no GPU. This run took {:.1} min. Machine speed in this run: \
         one safety-filter iteration at the working point of `cargo bench -p flowopt-planner --bench engine` \
         (16 robots, 2D) took {:.1} µs; docs/BENCHMARKS.md has {BENCHMARKS_SF_ITERATION_US} µs there, so \
         times here compare with that page's in that ratio. Every table and figure below comes from that one \
         run, on the same seeded test instances for every method (seeds {}..{}, {} per row; table 4 plans its \
         own batches, seeds shown; tables 7 and 8 plan scene families' instances from the same first seed, \
         at most as many per row, counts shown; training data uses seeds from 10^9), planned one at a time in one process, \
         wall-clock times per instance.\n\n\
         Methods: **baseline** is the from-scratch AM optimiser (smoothness cost, routed cold start, up to {} \
         restarts sharing an iteration cap of {}, fewer where that leaves an attempt under {} iterations per robot; \
         its robot pairs on two threads from {} robots); **flowopt** is the learned pipeline ({} flow candidates in {} \
         {:?} steps without obstacles, {} in {} with, {reroute}top {} by primal residual, {init}, safety filter on {} thread(s) without obstacles and {} with {metric} \
         with the penalty starting at {} and doubling every {} iterations up to {}, cap {}, {settle}; up to {} rounds of \
         sampling and refining while none verifies); **flow-no-init** is the same with the safety filter \
         started from the flow samples (the paper's ablation). Rows a method cannot plan say why. Success is \
         the dense verdict of `flowopt_planner::metrics` (every separation kept to 1% on 4K instants, box, \
         boundary conditions). Smoothness is the mean over robots of the sum of squared accelerations over \
         the team's K samples (m^2/s^4; K = 50, raised with the degree for workspaces over 6.8 m across, \
         `Team::resolved_for_workspace`: 59 for the crowd of 128 robots, 84 for 256, so their smoothness \
         sums more samples); min clearance is the smallest surface gap between two robots or a \
         robot and an obstacle (m).\n\n",
        f.command,
        machine(),
        f.seconds / 60.0,
        f.calibration_us,
        f.seed,
        f.seed + f.problems,
        f.problems,
        optimiser.restarts,
        optimiser.max_iterations,
        flowopt_planner::am::ATTEMPT_ITERATIONS_PER_ROBOT,
        flowopt_planner::am::TWO_THREADS_MIN_ROBOTS,
        pipeline.candidates,
        pipeline.steps,
        pipeline.solver,
        pipeline.obstacle_candidates,
        pipeline.obstacle_steps,
        pipeline.top_k,
        pipeline.threads,
        pipeline.obstacle_threads,
        filter.rho.initial,
        filter.rho.every,
        filter.rho.max,
        filter.max_iterations,
        pipeline.rounds,
    )
}

/// Table 1: method comparison over the team sizes.
fn method_comparison(runs: &mut Runs, command: &str) -> Result<String> {
    let mut table = Table::new(&[
        "team",
        "method",
        "success",
        "median ms",
        "p95 ms",
        "smoothness",
        "arc length (m)",
        "min clearance (m), mean / worst",
        "paper median ms (RTX 5090)",
    ]);
    for ((dim, robots), paper) in TEAMS.into_iter().zip(PAPER_MS) {
        for method in METHODS {
            let row = Row::new(dim, robots, 0, method);
            let lead = vec![row.label(), method.name().to_string()];
            let Some(records) = runs.for_table(row, &mut table, &lead)? else { continue };
            let ok: Vec<&Record> = records.iter().filter(|r| r.success).collect();
            let times: Vec<f64> = records.iter().map(|r| r.time_ms).collect();
            let clearance: Vec<f64> = ok.iter().map(|r| r.min_clearance).collect();
            let paper = match method {
                Method::Baseline => ms(paper.1),
                Method::Flowopt => ms(paper.0),
                _ => "-".into(),
            };
            let mut cells = lead;
            cells.extend([
                pct(ok.len() as f64 / records.len() as f64),
                ms(quantile(&times, 0.5)),
                ms(quantile(&times, 0.95)),
                num(mean(&ok.iter().map(|r| r.smoothness).collect::<Vec<_>>()), 2),
                num(mean(&ok.iter().map(|r| r.arc_length).collect::<Vec<_>>()), 3),
                format!(
                    "{} / {}",
                    num(mean(&clearance), 3),
                    num(clearance.iter().copied().fold(f64::NAN, f64::min), 3)
                ),
                paper,
            ]);
            table.row(cells);
        }
    }
    Ok(format!(
        "## 1. Method comparison\n\n{}\nCommand: `{command}`. The rows alone: `flowopt bench --method M --robots N \
         --dim D --problems P` (same seeds). Smoothness, arc length and clearance are over the successful \
         instances; times over all.\n\n",
        table.render()
    ))
}

/// Table 2: iterations to primal residual 0.01 and 0.001.
fn iterations(runs: &mut Runs, command: &str) -> Result<String> {
    let mut table = Table::new(&[
        "team",
        "method",
        "to 0.01: mean / min / max",
        "reached",
        "to 0.001: mean / min / max",
        "reached",
    ]);
    for (dim, robots) in [(Dim::Two, 16), (Dim::Two, 32), (Dim::Three, 16), (Dim::Three, 32)] {
        for method in METHODS {
            let row = Row::new(dim, robots, 0, method);
            let lead = vec![row.label(), method.name().to_string()];
            let Some(records) = runs.for_table(row, &mut table, &lead)? else { continue };
            let coarse = IterationStats::of(records.iter().map(|r| r.iterations_to_0_01));
            let fine = IterationStats::of(records.iter().map(|r| r.iterations_to_0_001));
            let mut cells = lead;
            for s in [coarse, fine] {
                cells.push(format!("{} / {} / {}", num(s.mean, 1), num(s.min, 0), num(s.max, 0)));
                cells.push(pct(s.reached));
            }
            table.row(cells);
        }
    }
    Ok(format!(
        "## 2. Iterations to primal residual 0.01 and 0.001 (m)\n\n{}\nCommand: `{command}`. A separate, untimed \
         residual study of each instance with no dense verification and a cap of 10,000 iterations: \
         the baseline from its cold start (routed straight lines, zero multiplier, its penalty schedule), the \
         learned methods from the chosen candidate's safety-filter start (the initialiser's output, or the \
         flow sample with a zero multiplier). Means, minima and maxima are over the instances that reached \
         the level.\n\n",
        table.render()
    ))
}

/// Table 3 and its figure: success rate as a function of the time budget.
fn success_versus_time(runs: &mut Runs, command: &str, dir: &Path, link: &str) -> Result<String> {
    let mut header = vec!["budget (ms)".to_string()];
    let mut curves = Vec::new();
    let mut columns = Vec::new();
    for (c, method) in METHODS.into_iter().enumerate() {
        let row = Row::new(Dim::Two, 16, OBSTACLES, method);
        if let Some(reason) = runs.unavailable(row) {
            header.push(format!("{} (not yet available: {reason})", method.name()));
            columns.push(None);
            continue;
        }
        header.push(method.name().to_string());
        let records = runs.get(row)?;
        let values: Vec<f64> = BUDGETS_MS.iter().map(|&b| success_within(records, b)).collect();
        curves.push(Curve {
            label: method.name().into(),
            colour: c,
            points: BUDGETS_MS.iter().copied().zip(values.iter().map(|v| 100.0 * v)).collect(),
        });
        columns.push(Some(values));
    }
    let mut table = Table::new(&header.iter().map(String::as_str).collect::<Vec<_>>());
    for (b, budget) in BUDGETS_MS.iter().enumerate() {
        let mut cells = vec![ms(*budget)];
        cells.extend(columns.iter().map(|c| c.as_ref().map_or("-".into(), |v| pct(v[b]))));
        table.row(cells);
    }
    let file = "success_vs_time.svg";
    figures::curves(
        &dir.join(file),
        "Success within a time budget: 16 robots, 2D, 8 obstacles",
        ("time budget (ms, log scale)", "instances solved (%)"),
        &curves,
        true,
        (0.0, 100.0),
    )?;
    Ok(format!(
        "## 3. Success rate against time budget (16 robots, 2D, {OBSTACLES} static obstacles)\n\n{}\nCommand: \
         `{command}`. Each instance is planned without a deadline; it counts at a budget when its plan \
         verified within that many milliseconds.\n\n![success against time budget]({link}/{file})\n\n",
        table.render()
    ))
}

/// Table 4: 50 problems x 10 candidates sampled and refined together.
fn throughput(args: &EvalArgs, command: &str) -> Result<String> {
    const PROBLEMS: usize = 50;
    const CANDIDATES: usize = 10;
    const REFINED: usize = 5;
    // Every one of the best REFINED is initialised and refined (the
    // paper's protocol and selection).
    let learned = LearnedArgs {
        candidates: CANDIDATES,
        obstacle_candidates: CANDIDATES,
        top_k: REFINED,
        smoothest: true,
        init_without_obstacles: true,
        // A batch is throughput work: both cores.
        threads: 2,
        ..args.learned.clone()
    };
    let mut planner = Planner::new(Overrides::default(), Some(learned.clone()));
    let team = Team::default_for(Dim::Two, 16);
    let sampling = format!("sampling {} candidates ms", PROBLEMS * CANDIDATES);
    let refinements = format!("{} SF refinements ms", PROBLEMS * REFINED);
    let mut table = Table::new(&[
        "batch (seeds)",
        "total ms",
        "per problem ms",
        &sampling,
        "rank ms",
        "init ms",
        &refinements,
        "success",
    ]);
    if let Some(reason) = planner.learned_unavailable(&team) {
        table.unavailable(&["-".into()], &reason);
    } else {
        let batches = if args.quick { 1 } else { 3 };
        for b in 0..batches {
            let first = args.seed + (b * PROBLEMS) as u64;
            let problems = (0..PROBLEMS as u64)
                .map(|i| RandomScenario::new(team.clone()).generate(first + i).map_err(anyhow::Error::from))
                .collect::<Result<Vec<_>>>()?;
            let (outcomes, total) = planner.plan_learned_batch(Method::Flowopt, &problems, 0, first)?;
            let t = outcomes.first().map(|o| o.times).unwrap_or_default();
            let verified = outcomes.iter().filter(|o| o.verified).count();
            table.row(vec![
                format!("{first}..{}", first + PROBLEMS as u64),
                ms(total),
                ms(total / PROBLEMS as f64),
                ms(t.sample_ms),
                ms(t.rank_ms),
                ms(t.init_ms),
                ms(t.filter_ms),
                pct(verified as f64 / PROBLEMS as f64),
            ]);
        }
    }
    Ok(format!(
        "## 4. Batched throughput (16 robots, 2D)\n\n{}\nCommand: `{command}`. {PROBLEMS} distinct problems x \
         {CANDIDATES} flow candidates sampled in one batch, the best {REFINED} per problem initialised in one \
         batch and refined by the safety filter on {} threads ({} refinements). Success: the problem's \
         returned plan verified. The paper (RTX 5090): 50 x 10 candidates sampled in under 60 ms, 250 SF \
         refinements in under 300 ms.\n\n",
        table.render(),
        learned.settings(Method::Flowopt).threads_for(0),
        PROBLEMS * REFINED
    ))
}

/// Table 5: an extra obstacle, unseen by the networks, at the safety filter.
fn robustness(runs: &mut Runs, command: &str, dir: &Path, link: &str) -> Result<String> {
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
fn clearance(runs: &mut Runs, command: &str, dir: &Path, link: &str) -> Result<String> {
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
fn residual_figure(runs: &mut Runs, dir: &Path, link: &str) -> Result<String> {
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
fn trajectory_figures(runs: &mut Runs, args: &EvalArgs, link: &str) -> Result<String> {
    let dir = &args.figures;
    let team = Team::default_for(Dim::Two, 16);
    let circle = antipodal(&team, 0.9).context("building the antipodal swap")?;
    let obstacles = Row::new(Dim::Two, 16, OBSTACLES, Method::Baseline).instance(args.seed)?;
    let moving = RandomScenario::new(team.clone())
        .with_obstacles(4)
        .with_obstacle_speed(0.3)
        .generate(args.seed)
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
        let plans = plan_each(runs, problem, &methods, args.seed)?;
        let panels: Vec<PlanPanel> =
            plans.iter().map(|(m, r)| PlanPanel { title: title(*m, r), problem, xi: &r.xi }).collect();
        figures::trajectories(&dir.join(file), &panels)?;
        let _ = write!(out, "The {what} (seed {}):\n\n![{what}]({link}/{file})\n\n", args.seed);
    }
    let plans = plan_each(runs, &moving, &methods, args.seed)?;
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
        args.seed,
        details.join("; ")
    );
    Ok(out)
}

/// Plans `problem` with every method (noise seed `seed`).
fn plan_each(runs: &mut Runs, problem: &Problem, methods: &[Method], seed: u64) -> Result<Vec<(Method, Record)>> {
    methods.iter().map(|&m| Ok((m, runs.planner.run(m, problem, seed)?))).collect()
}

fn title(method: Method, r: &Record) -> String {
    format!(
        "{}: {}, smoothness {:.2}, {:.1} ms",
        method.name(),
        if r.success { "verified" } else { "NOT verified" },
        r.smoothness,
        r.time_ms
    )
}
