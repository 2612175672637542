//! Training the SF initialiser through unrolled safety-filter iterations.

use std::path::{Path, PathBuf};

use candle_core::{DType, Device};
use candle_nn::{VarBuilder, VarMap};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use flowopt_planner::am::{AmSettings, Engine, Objective, Prepared};

use super::card::{card_input, write_card};
use super::data::{Batch, Reading, Split, split};
use super::run::run_loop;
use super::settings::{TrainConfig, TrainReport};
use crate::ModelError;
use crate::coding::Coding;
use crate::dataset::{Bucket, Dataset};
use crate::flow::{FlowConfig, FlowModel};
use crate::init::{InitConfig, InitModel, tokens_to_coefficients};
use crate::layers::{initialise, noise};
use crate::shipped::Weights;
use crate::unrolled::UnrolledSf;
use crate::weights::save;

/// Settings of the initialiser's training data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InitData {
    /// Training problems per bucket (the held-out ones are kept apart).
    pub per_bucket: usize,
    /// Flow sampling steps (Euler) that make the samples.
    pub flow_steps: usize,
}

/// The SF side of one bucket of initialiser training data (its tensors,
/// with the flow samples as tokens, are a [`Split`]).
pub(super) struct InitBucket {
    engine: Engine,
    sf: UnrolledSf,
    /// Prepared SF problems, their targets the flow samples.
    prepared: Vec<Prepared>,
}

/// Trains the initialiser through `init.unroll` unrolled SF iterations on
/// samples of the flow model at `flow_path`, and writes `out` and its card.
#[allow(clippy::too_many_arguments)]
pub fn train_init(
    data: &[(PathBuf, Dataset)],
    flow_path: &Path,
    init: &InitConfig,
    samples: &InitData,
    cfg: &TrainConfig,
    out: &Path,
    checkpoint_dir: &Path,
    progress: impl FnMut(usize, f64, Option<f64>),
) -> Result<TrainReport, ModelError> {
    let flow = crate::weights::load::<FlowConfig>(&Weights::File(flow_path.to_path_buf()), "flow")?;
    let stats = flow.stats.clone();
    let flow_net = FlowModel::new(flow.vars, &flow.config)?;
    let reading = Reading::of(&flow.config)?;
    let all = split(data, &stats, &reading, cfg.validation_fraction)?;
    // Keep per bucket the first `per_bucket` training and up to a quarter
    // as many held-out instances, and make their flow samples.
    let mut splits = Vec::new();
    let mut buckets = Vec::new();
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed ^ 0x1417);
    for s in all {
        let (n, m) = (s.data.robots, s.data.obstacles);
        let train = s.train.min(samples.per_bucket);
        let held = (samples.per_bucket / 4).max(1).min(s.data.len() - s.train);
        let ids: Vec<u32> = (0..train as u32).chain(s.train as u32..(s.train + held) as u32).collect();
        let Batch { robots, obstacles, pairs, .. } = s.batch(&ids)?;
        // The bucket's instances, in their family's workspace.
        let config = &data[s.source].1.manifest.config;
        let team = config.problem(n, m, s.data.seeds[0])?.team;
        // The unrolled filter projects onto the fixed separation (no chord
        // inflation): its engine must too.
        let settings = AmSettings { chord: false, ..AmSettings::safety_filter() };
        let engine = Engine::new(&team, m, Objective::filter(init.sf_smoothing), settings)?;
        let sf = UnrolledSf::new(&engine, DType::F32)?;
        let coding = Coding::new(&team)?;
        let encoded = flow_net.encode(&robots, &obstacles, pairs.as_ref())?;
        let x0 = noise(&mut rng, &[ids.len(), n, flow.config.token_width()], &Device::Cpu)?;
        let sampled = flow_net
            .sample(&x0, &encoded, samples.flow_steps, crate::flow::Solver::Euler, &|| false)?
            .ok_or_else(|| ModelError::Config("sampling cannot stop here".into()))?;
        let raw = reading.tokens.to_coefficients(&stats.token.denormalise(&sampled)?)?;
        let width = flow.config.token_width() * n;
        let raw = raw.flatten_all()?.to_vec1::<f32>()?;
        let mut prepared = Vec::with_capacity(ids.len());
        for (j, &id) in ids.iter().enumerate() {
            let problem = config.problem(n, m, s.data.seeds[id as usize])?;
            if problem.team != team {
                return Err(ModelError::Config(format!(
                    "{}: the {} family's instances lie in workspaces that vary with the seed; the initialiser \
                     trains through one safety filter per bucket",
                    data[s.source].0.display(),
                    config.family.name()
                )));
            }
            let sample = coding.decode(&coding.reference(&problem), &raw[j * width..(j + 1) * width]);
            prepared.push(engine.prepare(&problem, Some(&sample))?);
        }
        let seeds = ids.iter().map(|&i| s.data.seeds[i as usize]).collect();
        let data =
            Bucket { robots: n, obstacles: m, seeds, robot_rows: robots, obstacle_rows: obstacles, tokens: sampled };
        splits.push(Split { data, train, source: s.source, pairs: None });
        buckets.push(InitBucket { engine, sf, prepared });
    }
    let mut vars = VarMap::new();
    let net = InitModel::new(VarBuilder::from_varmap(&vars, DType::F32, &Device::Cpu), init)?;
    initialise(&vars, cfg.seed)?;
    let report = run_loop(
        "init",
        &mut vars,
        cfg,
        &splits,
        checkpoint_dir,
        |k, ids, _rng| {
            let b = &buckets[k];
            let rows = splits[k].batch(ids)?;
            let out = net.forward(&rows.tokens, &rows.robots, &rows.obstacles)?;
            let chosen: Vec<&Prepared> = ids.iter().map(|&i| &b.prepared[i as usize]).collect();
            let batch = b.sf.batch(&b.engine, &chosen)?;
            let delta = reading.tokens.to_coefficients(&stats.token.scale(&out.delta)?)?;
            let delta = tokens_to_coefficients(&delta, init.dim, init.n_xi)?;
            let xi0 = (&batch.sample + delta)?;
            let (xi_l, _, residuals) = b.sf.unroll(&xi0, &out.lambda, &batch, init.unroll)?;
            let fixed_point = residuals.sum(0)?.mean_all()?;
            let distance = b.sf.distance(&xi_l, &batch)?.mean_all()?;
            Ok((fixed_point + distance)?)
        },
        progress,
    )?;
    save(out, &vars, "init", init, &stats)?;
    write_card(out, "init", init, cfg, data, vec![card_input(flow_path)?], &splits, &report)?;
    Ok(report)
}
