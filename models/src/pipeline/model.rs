//! The networks: the flow policy and the optional SF initialiser, loaded
//! from weight files, and the flow's sampling of candidates.

use candle_core::{Device, Tensor};
use flowopt_planner::am::Budget;
use flowopt_planner::problem::Team;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use super::outcome::Query;
use super::settings::PipelineSettings;
use crate::ModelError;
use crate::coding::{conditions, obstacle_width, robot_width};
use crate::flow::{FlowConfig, FlowModel};
use crate::init::{InitConfig, InitModel};
use crate::layers::noise;
use crate::shipped::Weights;
use crate::tokens::TokenMap;
use crate::weights::{Stats, load};

/// The learned planner: a flow policy and optionally an initialiser.
#[derive(Debug, Clone)]
pub struct FlowOpt {
    pub(super) flow: FlowModel,
    pub(super) stats: Stats,
    pub(super) tokens: TokenMap,
    pub(super) init: Option<InitModel>,
}

impl FlowOpt {
    /// Loads the flow policy at `flow` and the initialiser at `init`; the
    /// initialiser must share the policy's statistics.
    pub fn load(flow: &Weights, init: Option<&Weights>) -> Result<Self, ModelError> {
        let f = load::<FlowConfig>(flow, "flow")?;
        let model = FlowModel::new(f.vars, &f.config)?;
        let tokens = TokenMap::new(f.config.tokens, f.config.dim, f.config.n_xi)?;
        let init = match init {
            Some(weights) => {
                let i = load::<InitConfig>(weights, "init")?;
                if i.stats != f.stats || i.config.dim != f.config.dim || i.config.n_xi != f.config.n_xi {
                    return Err(ModelError::Config(format!("{weights} was not trained on samples of {flow}")));
                }
                Some(InitModel::new(i.vars, &i.config)?)
            }
            None => None,
        };
        Ok(Self { flow: model, stats: f.stats, tokens, init })
    }

    /// Whether an initialiser is loaded.
    pub fn has_init(&self) -> bool {
        self.init.is_some()
    }

    /// Whether the networks were built for `team`'s dimension and basis.
    pub fn check(&self, team: &Team) -> Result<(), ModelError> {
        let c = self.flow.config();
        if c.dim != team.dim.axes() || c.n_xi != team.degree + 1 {
            return Err(ModelError::Config(format!(
                "the flow model plans {}D with {} coefficients, the team is {}D with {}",
                c.dim,
                c.n_xi,
                team.dim.axes(),
                team.degree + 1
            )));
        }
        Ok(())
    }

    /// Samples `count` normalised token sets per query (whose reference
    /// curves are `references`) with noise seeded by `seed`, all queries in
    /// one batch; returns them `[P count, n, W]` (query-major) with the
    /// normalised condition rows `[P, n, .]` and `[P, m, .]`.
    pub(super) fn sample(
        &self,
        queries: &[Query<'_>],
        references: &[Vec<f64>],
        count: usize,
        settings: &PipelineSettings,
        seed: u64,
        budget: &Budget<'_>,
    ) -> Result<(Tensor, Tensor, Tensor), ModelError> {
        let first = queries[0].seen;
        let dim = first.team.dim.axes();
        let (p, n, m) = (queries.len(), first.robots(), first.obstacles.len());
        let (mut robot_rows, mut obstacle_rows) = (Vec::new(), Vec::new());
        for q in queries {
            let (r, o) = conditions(q.seen);
            robot_rows.extend(r);
            obstacle_rows.extend(o);
        }
        let robots =
            self.stats.robot.normalise(&Tensor::from_vec(robot_rows, (p, n, robot_width(dim)), &Device::Cpu)?)?;
        let obstacles = self.stats.obstacle.normalise(&Tensor::from_vec(
            obstacle_rows,
            (p, m, obstacle_width(dim)),
            &Device::Cpu,
        )?)?;
        let pairs = if self.flow.reads_pairs() && m > 0 {
            let rows = queries.iter().zip(references).flat_map(|(q, r)| crate::pairs::pair_rows(q.seen, r)).collect();
            Some(Tensor::from_vec(rows, (p, n, m, crate::pairs::pair_width(dim)), &Device::Cpu)?)
        } else {
            None
        };
        let encoded = self.flow.encode(&robots, &obstacles, pairs.as_ref())?;
        // One problem's conditioning broadcasts over its candidates (the
        // per-robot adaLN then runs once, not once per candidate); several
        // problems need it per candidate.
        let encoded = if p == 1 { encoded } else { encoded.repeat_each(count)? };
        let steps = settings.steps_for(m);
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let x0 =
            (noise(&mut rng, &[p * count, n, self.flow.config().token_width()], &Device::Cpu)? * settings.temperature)?;
        // The candidates split between the threads, each integrating its
        // share on one core (candle itself runs one thread when planning).
        let rows = p * count;
        let threads = settings.threads_for(m).clamp(1, rows);
        let share = rows.div_ceil(threads);
        let parts = crate::runtime::parallel(threads, threads, |t| {
            let (first, len) = (t * share, share.min(rows.saturating_sub(t * share)));
            if len == 0 {
                return Ok(None);
            }
            let part = encoded.rows(first, len)?;
            let x = x0.narrow(0, first, len)?;
            let sampled = self.flow.sample(&x, &part, steps, settings.solver, &|| budget.spent().is_some())?;
            Ok(Some(sampled.ok_or(ModelError::Stopped)?))
        })?;
        let tokens = if parts.len() == 1 { parts[0].clone() } else { Tensor::cat(&parts, 0)? };
        Ok((tokens, robots, obstacles))
    }
}
