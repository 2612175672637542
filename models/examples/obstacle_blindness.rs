//! How much the flow policy's samples avoid static obstacles, against the
//! straight (smoothest) curves: the diagnosis behind the pipeline's
//! rerouting and the pair rows (docs/LEARNED.md).
//!
//! `cargo run --release -p flowopt-models --example obstacle_blindness [problems] [flow weights] [robots] [steps]`
//! on unseen 8-obstacle instances (seeds 0..problems, default 100) of 16
//! robots unless told, sampled in the pipeline's steps for obstacles unless
//! told, with the shipped 2D flow weights unless others are given.
//!
//! Besides the count of robots through an obstacle, it splits the robots
//! by whether their straight curve is blocked (comes within a scaled
//! distance of 1 of an obstacle): a policy that reads the obstacles moves
//! the blocked ones out and leaves the others clear. The optimiser's plans,
//! the training data, pass blocked robots at 1.0-1.25, so samples of a
//! policy that learnt them scatter around 1: the share at 0.6 or more
//! tells more than the share at 1.

use flowopt_models::coding::Coding;
use flowopt_models::pipeline::{FlowOpt, PipelineSettings};
use flowopt_models::shipped::Weights;
use flowopt_planner::am::{AmSettings, Budget, Engine, Objective};
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Dim, Problem, Team, scaled_norm};
use flowopt_planner::scenario::RandomScenario;

/// Every robot's closest scaled distance to an obstacle (1: touching) on
/// 200 instants of plan `xi`.
fn closest(problem: &Problem, xi: &[f64]) -> Vec<f64> {
    let plan = JointPlan::new(&problem.team, xi.to_vec());
    let mut closest = vec![f64::INFINITY; problem.robots()];
    for s in 0..200 {
        let t = problem.team.horizon * s as f64 / 199.0;
        for (c, k) in closest.iter_mut().zip(plan.at(t)) {
            for o in &problem.obstacles {
                let (a, b) = problem.team.obstacle_separation(&o.shape);
                *c = c.min(scaled_norm(problem.team.dim, &(k.position - o.at(t)), a, b));
            }
        }
    }
    closest
}

/// Mean absolute difference between two coefficient vectors (m).
fn mean_abs(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).sum::<f64>() / a.len() as f64
}

/// Share of `values` at least `level`.
fn share(values: &[f64], level: f64) -> f64 {
    values.iter().filter(|&&v| v >= level).count() as f64 / values.len().max(1) as f64
}

fn main() -> anyhow::Result<()> {
    let problems: u64 = std::env::args().nth(1).map(|s| s.parse()).transpose()?.unwrap_or(100);
    let weights = std::env::args().nth(2).map_or_else(|| Weights::shipped_flow(Dim::Two), |w| Weights::parse(&w));
    let robots: usize = std::env::args().nth(3).map(|s| s.parse()).transpose()?.unwrap_or(16);
    let team = Team::default_for(Dim::Two, robots);
    let flow = FlowOpt::load(&weights, None)?;
    let filters = [0, 8].map(|m| Engine::new(&team, m, Objective::Projection, AmSettings::safety_filter()));
    let [Ok(free), Ok(cluttered)] = filters else { anyhow::bail!("building the safety filters") };
    let coding = Coding::new(&team)?;
    let defaults = PipelineSettings::default();
    let steps: usize = std::env::args().nth(4).map(|s| s.parse()).transpose()?.unwrap_or(defaults.obstacle_flow_steps);
    let settings = PipelineSettings {
        top_k: 1,
        use_init: false,
        reroute: false,
        rounds: 1,
        obstacle_flow_steps: steps,
        ..defaults
    };
    // The policy sees the obstacles or not; everything else is the same.
    let blind_settings = PipelineSettings {
        candidates: settings.obstacle_candidates,
        flow_steps: settings.obstacle_flow_steps,
        ..settings.clone()
    };
    let (mut straight, mut sampled) = ([0usize; 2], [0usize; 2]);
    let (mut blocked, mut clear) = (Vec::new(), Vec::new());
    let (mut conditioning, mut spread) = (0.0, 0.0);
    for seed in 0..problems {
        let problem = RandomScenario::new(team.clone()).with_obstacles(8).generate(seed)?;
        let line = closest(&problem, &coding.reference(&problem));
        let with = flow.plan(&problem, &cluttered, &settings, seed, &Budget::unlimited())?.samples;
        let mut blind = problem.clone();
        blind.obstacles.clear();
        let without = flow.plan(&blind, &free, &blind_settings, seed, &Budget::unlimited())?.samples;
        for (k, level) in [0.6, 1.0].into_iter().enumerate() {
            straight[k] += line.iter().filter(|&&c| c < level).count();
        }
        for x in &with {
            let sample = closest(&problem, x);
            for (k, level) in [0.6, 1.0].into_iter().enumerate() {
                sampled[k] += sample.iter().filter(|&&c| c < level).count();
            }
            for (&l, &s) in line.iter().zip(&sample) {
                if l < 1.0 { blocked.push(s) } else { clear.push(s) }
            }
        }
        conditioning += with.iter().zip(&without).map(|(a, b)| mean_abs(a, b)).sum::<f64>() / with.len() as f64;
        spread += with.windows(2).map(|w| mean_abs(&w[0], &w[1])).sum::<f64>() / (with.len() - 1) as f64;
    }
    let per = |x: usize, count: usize| x as f64 / (problems as usize * count) as f64;
    let candidates = settings.obstacle_candidates;
    println!("robots per problem through an obstacle (scaled distance < 1; < 0.6 in brackets):");
    println!("  straight curves {:.2} ({:.2})", per(straight[1], 1), per(straight[0], 1));
    println!("  flow samples    {:.2} ({:.2})", per(sampled[1], candidates), per(sampled[0], candidates));
    println!(
        "samples of robots whose straight curve is blocked: {:.0}% at >= 1, {:.0}% at >= 0.6 (straight: 0%, {:.0}%)",
        100.0 * share(&blocked, 1.0),
        100.0 * share(&blocked, 0.6),
        100.0 * (1.0 - per(straight[0], 1) / per(straight[1], 1).max(1e-9)),
    );
    println!("samples of robots whose straight curve is clear: {:.0}% stay at >= 1", 100.0 * share(&clear, 1.0));
    println!(
        "mean |coefficient change| when the obstacles are hidden from the policy: {:.4} m; between candidates: {:.4} m",
        conditioning / problems as f64,
        spread / problems as f64
    );
    Ok(())
}
