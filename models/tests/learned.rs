//! The learned planner end to end on tiny data: datagen, a few training
//! steps of each network (the loss must fall), weight files, and the
//! pipeline. No real model is trained here.

use std::path::{Path, PathBuf};
use std::time::Duration;

use flowopt_models::ModelError;
use flowopt_models::coding::Coding;
use flowopt_models::datagen::generate;
use flowopt_models::dataset::{DataSolver, DatagenConfig, Dataset, WeightFile};
use flowopt_models::flow::FlowConfig;
use flowopt_models::init::InitConfig;
use flowopt_models::pipeline::{
    DEFAULT_SF_SMOOTHING, FlowOpt, LearnedPipeline, LearnedPlanner, PipelineSettings, Settle,
};
use flowopt_models::shipped::Weights;
use flowopt_models::train::{FlowStart, InitData, TrainConfig, train_flow, train_init};
use flowopt_planner::am::{AmSettings, AmState, Budget, Engine, Objective, Stop};
use flowopt_planner::method::Planner;
use flowopt_planner::metrics::Metrics;
use flowopt_planner::optimiser::Optimiser;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::Problem;
use flowopt_planner::scenes::Family;

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("flowopt-learned-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    dir
}

fn tiny_data(dir: &Path) -> (DatagenConfig, Vec<(PathBuf, Dataset)>) {
    let config = DatagenConfig {
        family: Family::Random,
        dim: 2,
        robots: vec![4],
        max_obstacles: 1,
        start_speed: 0.2,
        per_bucket: 96,
        shard_size: 24,
        first_seed: 1_000_000_000,
        solver: DataSolver::Optimiser,
    };
    generate(&config, dir, 2, &optimiser, |_| {}).unwrap();
    (config, vec![(dir.to_path_buf(), Dataset::load(dir).unwrap())])
}

/// The optimiser with its defaults, as `datagen` solves with it.
fn optimiser() -> Result<Box<dyn Planner>, ModelError> {
    Ok(Box::new(Optimiser::new(AmSettings::optimiser())))
}

fn train_config(steps: usize) -> TrainConfig {
    TrainConfig {
        steps,
        tokens_per_batch: 64,
        lr: 3e-3,
        lr_min: 1e-4,
        warmup: 2,
        clip: 1.0,
        seed: 7,
        validation_fraction: 0.2,
        checkpoint_every: steps,
    }
}

#[test]
fn tiny_networks_learn_and_the_pipeline_plans_with_them() {
    let dir = scratch("all");
    let (config, data) = tiny_data(&dir.join("data"));
    let flow_cfg = FlowConfig { width: 32, heads: 2, layers: 1, hidden: 32, time_freqs: 8, ..FlowConfig::small(2, 11) };
    let flow_path = dir.join("flow.safetensors");
    let fresh = FlowStart::Fresh(flow_cfg);
    let report = train_flow(&data, &fresh, &train_config(40), &flow_path, &dir.join("ck"), |_, _, _| {}).unwrap();
    assert!(
        report.validation_loss < report.first_validation_loss,
        "flow validation loss {} -> {}",
        report.first_validation_loss,
        report.validation_loss
    );
    assert!(flow_path.with_extension("json").exists(), "a model card is written");

    // Fine-tuning from those weights starts where they ended (the same
    // validation loss before its first step: same weights, statistics and
    // held-out noise), lowers its loss, and names its start in the card.
    let tuned_path = dir.join("tuned.safetensors");
    let from = FlowStart::From(flow_path.clone());
    let tuned = train_flow(&data, &from, &train_config(20), &tuned_path, &dir.join("ck-tuned"), |_, _, _| {}).unwrap();
    assert!(
        (tuned.first_validation_loss - report.validation_loss).abs() < 1e-5,
        "fine-tuning starts from the trained weights: {} against {}",
        tuned.first_validation_loss,
        report.validation_loss
    );
    assert!(tuned.validation_loss < tuned.first_validation_loss);
    let card = std::fs::read_to_string(tuned_path.with_extension("json")).unwrap();
    assert!(card.contains(&flow_path.display().to_string()), "{card}");

    // Through the smoothness-weighted SF: its linear term is not the sample.
    let init_cfg =
        InitConfig { width: 16, heads: 2, hidden: 16, unroll: 4, sf_smoothing: 3.0, ..InitConfig::small(2, 11) };
    let init_path = dir.join("init.safetensors");
    let samples = InitData { per_bucket: 60, flow_steps: 2 };
    let report = train_init(
        &data,
        &flow_path,
        &init_cfg,
        &samples,
        &TrainConfig { lr: 1e-3, ..train_config(80) },
        &init_path,
        &dir.join("ck"),
        |_, _, _| {},
    )
    .unwrap();
    assert!(
        report.validation_loss < report.first_validation_loss,
        "init validation loss {} -> {}",
        report.first_validation_loss,
        report.validation_loss
    );

    // The pipeline with both networks on an unseen instance.
    let planner = FlowOpt::load(&Weights::File(flow_path.clone()), Some(&Weights::File(init_path.clone()))).unwrap();
    let team = flowopt_planner::problem::Team::default_for(flowopt_planner::problem::Dim::Two, 4);
    let problem = flowopt_planner::scenario::RandomScenario::new(team.clone()).with_obstacles(1).generate(3).unwrap();
    let sf = Engine::new(&team, 1, Objective::filter(init_cfg.sf_smoothing), AmSettings::safety_filter()).unwrap();
    let settings = PipelineSettings {
        candidates: 5,
        obstacle_candidates: 6,
        obstacle_flow_steps: 2,
        top_k: 3,
        settle: Settle::Smoothest,
        ..PipelineSettings::default()
    };
    let out = planner.plan(&problem, &sf, &settings, 1, &Budget::unlimited()).unwrap();
    assert_eq!((out.samples.len(), out.refined.len()), (6, 3));
    // The same robots without the obstacle: `candidates` samples.
    let free = Problem { obstacles: Vec::new(), ..problem.clone() };
    let free_sf = Engine::new(&team, 0, Objective::filter(init_cfg.sf_smoothing), AmSettings::safety_filter()).unwrap();
    assert_eq!(planner.plan(&free, &free_sf, &settings, 1, &Budget::unlimited()).unwrap().samples.len(), 5);
    // The initialiser starts the filter where there are obstacles, and
    // without them only when asked to.
    let starts = |problem: &Problem, sf: &Engine, settings: &PipelineSettings| -> Vec<AmState> {
        let out = planner.plan(problem, sf, settings, 1, &Budget::unlimited()).unwrap();
        out.refined.into_iter().map(|r| r.start).collect()
    };
    let none = PipelineSettings { use_init: false, ..settings.clone() };
    let everywhere = PipelineSettings { init_without_obstacles: true, ..settings.clone() };
    assert_eq!(starts(&free, &free_sf, &settings), starts(&free, &free_sf, &none));
    assert_ne!(starts(&free, &free_sf, &everywhere), starts(&free, &free_sf, &none));
    assert_ne!(starts(&problem, &sf, &settings), starts(&problem, &sf, &none));
    assert!(out.refined.windows(2).all(|w| w[0].sample_primal <= w[1].sample_primal), "ranked by primal residual");
    let m = Metrics::measure(&problem, &JointPlan::new(&team, out.xi().to_vec()));
    assert!(m.boundary_error < 1e-6, "every plan meets the boundary conditions: {}", m.boundary_error);
    assert_eq!(out.verified, m.success(team.separation().0), "a verified plan passes the success verdict");
    assert!(out.stages.sample > Duration::ZERO && out.stages.filter > Duration::ZERO, "{:?}", out.stages);
    // Same seed, same plan; another seed, other samples.
    let again = planner.plan(&problem, &sf, &settings, 1, &Budget::unlimited()).unwrap();
    assert_eq!(again.xi(), out.xi());
    let other = planner.plan(&problem, &sf, &settings, 2, &Budget::unlimited()).unwrap();
    assert_ne!(other.samples[0], out.samples[0]);

    // Stopping at the first verified candidate returns the best-ranked one
    // that verifies when every candidate runs to its end, on any number of
    // threads; the candidates ranked above it ran to their end.
    let best = out.refined.iter().position(|r| r.outcome.stop == Stop::Verified).expect("a candidate verifies");
    for threads in [1, 2] {
        let first =
            PipelineSettings { settle: Settle::FirstVerified, threads, obstacle_threads: threads, ..settings.clone() };
        let got = planner.plan(&problem, &sf, &first, 1, &Budget::unlimited()).unwrap();
        assert!(got.verified);
        assert_eq!(got.refined[got.chosen].rank, best, "{threads} threads");
        assert_eq!(got.xi(), out.refined[best].outcome.state.xi.as_slice(), "{threads} threads");
        assert_eq!(got.samples, out.samples, "{threads} threads: the same samples");
        for r in got.refined.iter().filter(|r| r.rank < best) {
            assert_eq!(r.outcome.stop, out.refined[r.rank].outcome.stop);
        }
    }

    // Rounds: a first round that verifies is the plan. Where the filter
    // cannot verify (capped at one iteration), later rounds sample afresh
    // and the plan with the lowest primal residual of them all is kept.
    let once = PipelineSettings { rounds: 1, ..settings.clone() };
    assert_eq!(planner.plan(&problem, &sf, &once, 1, &Budget::unlimited()).unwrap().xi(), out.xi());
    let capped = AmSettings { max_iterations: 1, ..AmSettings::safety_filter() };
    let capped = Engine::new(&team, 1, Objective::filter(init_cfg.sf_smoothing), capped).unwrap();
    let rounds = PipelineSettings { rounds: 4, ..settings.clone() };
    let mut improved = 0;
    for seed in 0..8 {
        let one = planner.plan(&problem, &capped, &once, seed, &Budget::unlimited()).unwrap();
        let many = planner.plan(&problem, &capped, &rounds, seed, &Budget::unlimited()).unwrap();
        if one.verified {
            assert_eq!(many.xi(), one.xi(), "seed {seed}: no second round after a verified one");
        } else {
            assert!(many.primal() <= one.primal(), "seed {seed}: {} > {}", many.primal(), one.primal());
            improved += usize::from(many.primal() < one.primal());
        }
    }
    assert!(improved > 0, "later rounds found lower residuals");

    // A dataset solved by that pipeline keeps its verified plans, seeded by
    // the instances' seeds; weights that changed since the dataset began
    // are refused.
    let piped = DatagenConfig {
        per_bucket: 4,
        shard_size: 4,
        solver: DataSolver::Pipeline {
            flow: WeightFile::hashed(&flow_path).unwrap(),
            init: Some(WeightFile::hashed(&init_path).unwrap()),
        },
        ..config.clone()
    };
    let learned = || -> Result<Box<dyn Planner>, ModelError> {
        let settings =
            PipelineSettings { threads: 1, obstacle_threads: 1, use_init: true, ..PipelineSettings::default() };
        let planner = LearnedPlanner::load(
            &Weights::File(flow_path.clone()),
            Some(&Weights::File(init_path.clone())),
            DEFAULT_SF_SMOOTHING,
        )?;
        Ok(Box::new(LearnedPipeline::new(planner, settings, AmSettings::safety_filter())))
    };
    let manifest = generate(&piped, &dir.join("piped"), 2, &learned, |_| {}).unwrap();
    assert!(manifest.kept > 0, "the pipeline verifies 4-robot instances");
    let solved = Dataset::load(&dir.join("piped")).unwrap();
    let bucket = solved.buckets.iter().find(|b| !b.is_empty()).unwrap();
    let seed = bucket.seeds[0];
    let instance = piped.problem(bucket.robots, bucket.obstacles, seed).unwrap();
    let filter =
        Engine::new(&team, bucket.obstacles, Objective::filter(DEFAULT_SF_SMOOTHING), AmSettings::safety_filter())
            .unwrap();
    let one_thread = PipelineSettings { threads: 1, obstacle_threads: 1, ..PipelineSettings::default() };
    let planned = planner.plan(&instance, &filter, &one_thread, seed, &Budget::unlimited()).unwrap();
    assert!(planned.verified);
    let coding = Coding::new(&team).unwrap();
    let expected = coding.encode(&coding.reference(&instance), planned.xi());
    let stored = bucket.tokens.get(0).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    assert_eq!(stored, expected, "the stored plan is the pipeline's");
    let changed = DataSolver::Pipeline {
        flow: WeightFile { path: init_path.clone(), ..WeightFile::hashed(&flow_path).unwrap() },
        init: None,
    };
    let refused = generate(&DatagenConfig { solver: changed, ..piped }, &dir.join("changed"), 1, &learned, |_| {});
    assert!(matches!(refused, Err(ModelError::Config(_))), "{refused:?}");

    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn an_untrained_initialiser_is_the_plain_start() {
    let dir = scratch("identity");
    let (_config, data) = tiny_data(&dir.join("data"));
    let flow_cfg = FlowConfig { width: 16, heads: 2, layers: 1, hidden: 16, time_freqs: 4, ..FlowConfig::small(2, 11) };
    let flow_path = dir.join("flow.safetensors");
    train_flow(&data, &FlowStart::Fresh(flow_cfg), &train_config(2), &flow_path, &dir.join("ck"), |_, _, _| {})
        .unwrap();
    // Zero training steps: the initialiser keeps its zero output heads.
    let init_path = dir.join("init.safetensors");
    let init_cfg = InitConfig { width: 16, heads: 2, hidden: 16, unroll: 2, ..InitConfig::small(2, 11) };
    let cfg = TrainConfig { steps: 0, ..train_config(1) };
    train_init(
        &data,
        &flow_path,
        &init_cfg,
        &InitData { per_bucket: 4, flow_steps: 1 },
        &cfg,
        &init_path,
        &dir.join("ck"),
        |_, _, _| {},
    )
    .unwrap();
    let planner = FlowOpt::load(&Weights::File(flow_path.clone()), Some(&Weights::File(init_path.clone()))).unwrap();
    let team = flowopt_planner::problem::Team::default_for(flowopt_planner::problem::Dim::Two, 4);
    let problem = flowopt_planner::scenario::RandomScenario::new(team.clone()).generate(5).unwrap();
    let sf = Engine::new(&team, 0, Objective::Projection, AmSettings::safety_filter()).unwrap();
    let with = PipelineSettings {
        candidates: 4,
        flow_steps: 1,
        obstacle_flow_steps: 1,
        top_k: 2,
        init_without_obstacles: true,
        ..PipelineSettings::default()
    };
    let without = PipelineSettings { use_init: false, ..with.clone() };
    let a = planner.plan(&problem, &sf, &with, 9, &Budget::unlimited()).unwrap();
    let b = planner.plan(&problem, &sf, &without, 9, &Budget::unlimited()).unwrap();
    for (x, y) in a.refined.iter().zip(&b.refined) {
        assert_eq!(x.start, y.start);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
