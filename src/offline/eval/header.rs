//! The report's opening: the run, the machine's speed and the methods'
//! settings in words.

use std::time::Instant;

use anyhow::Result;
use flowopt_methods::PlannerSettings;
use flowopt_models::pipeline::Settle;
use flowopt_planner::problem::Dim;
use flowopt_planner::working_point::WorkingPoint;

use crate::offline::stats::quantile;

/// docs/BENCHMARKS.md's criterion time of one 16-robot 2D safety-filter
/// iteration (µs), the reference of the report's machine-speed line.
const BENCHMARKS_SF_ITERATION_US: f64 = 12.75;

/// Median time (µs) of one safety-filter iteration at the criterion
/// benchmark's working point ([`WorkingPoint`], 16 robots, 2D), measured in
/// this run so that runs on machines of different speed can be compared.
pub(super) fn calibration_us() -> Result<f64> {
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
pub(super) fn machine() -> String {
    let cores = std::thread::available_parallelism().map_or(1, std::num::NonZeroUsize::get);
    #[cfg(target_arch = "x86_64")]
    let avx2 = std::arch::is_x86_feature_detected!("avx2");
    #[cfg(not(target_arch = "x86_64"))]
    let avx2 = false;
    format!("{cores} cores{}", if avx2 { " (AVX2)" } else { "" })
}

/// What the report says of its run and its methods.
pub(super) struct HeaderFacts<'a> {
    pub(super) command: &'a str,
    pub(super) problems: u64,
    pub(super) seed: u64,
    pub(super) seconds: f64,
    pub(super) calibration_us: f64,
    pub(super) settings: &'a PlannerSettings,
}

pub(super) fn header(f: &HeaderFacts) -> String {
    let optimiser = f.settings.optimiser();
    let pipeline = f.settings.learned();
    let settle = match pipeline.settle {
        Settle::FirstVerified => {
            "taking the candidates in rank order and returning the best-ranked one that verifies (the candidates \
             are sampled on the filter's threads)"
        }
        Settle::Smoothest => "returning the verified plan with the lowest smoothness",
    };
    let filter = f.settings.filter;
    let reroute = if pipeline.reroute {
        "robots a sample leaves inside a static obstacle rerouted around the obstacles (`am::Rerouter`), "
    } else {
        ""
    };
    let metric = if pipeline.sf_smoothing > 0.0 {
        format!(
            "in the smoothness-weighted metric with weight {} (`Objective::SmoothProjection`, docs/LEARNED.md)",
            pipeline.sf_smoothing
        )
    } else {
        "as the plain projection".to_string()
    };
    let init = if pipeline.init_without_obstacles {
        "the SF initialiser"
    } else {
        "the SF initialiser where there are obstacles (without them the filter starts from the samples, so \
         there `flowopt` and `flow-no-init` plan alike: docs/LEARNED.md, \"The initialiser where it can \
         matter\"; `flowopt eval --set learned.init_without_obstacles=true` gives the paper's ablation there)"
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
         where the cold start routed robots around static obstacles, attempts that make no progress for {} \
         iterations end and the next moves when each routed robot passes its route's narrowest point, while the cap lasts; \
         on {} thread(s) from {} robots, the same plans for every count); **flowopt** is the learned pipeline ({} flow candidates in {} \
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
        optimiser.stall,
        f.settings.threads(),
        flowopt_planner::am::CREW_MIN_ROBOTS,
        pipeline.candidates,
        pipeline.flow_steps,
        pipeline.solver,
        pipeline.obstacle_candidates,
        pipeline.obstacle_flow_steps,
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
