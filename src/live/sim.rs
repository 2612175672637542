//! `flowopt sim`: simulated mocap and controllers. A team of
//! double-integrator robots tracks the newest plan with a PD controller plus
//! the plan's acceleration as feedforward, and publishes its measured state
//! at the control rate. When every robot has reached its goal, the team
//! gets new goals. The published states carry mocap noise and the robots an
//! unmodelled acceleration disturbance (seeded), so tracking is imperfect
//! as on real robots. Reports plans, state-to-plan latency, collisions and
//! tracking error.

use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use flowopt_client::clock::monotonic_ns;
use flowopt_client::{Endpoint, JointTrajectory, PlanStatus, StatePublisher, TeamChannel};
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Problem, StartState, Team};
use flowopt_planner::scenario::RandomScenario;
use hdrhistogram::Histogram;
use nalgebra::Vector3;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use crate::live::daemon_args::DaemonArgs;

/// Position gain (1/s^2): with `KD` a critically damped 5 rad/s loop.
const KP: f64 = 25.0;
/// Velocity gain (1/s).
const KD: f64 = 10.0;
/// Integration substeps per control period.
const SUBSTEPS: usize = 10;
/// A robot is at its goal within this distance (m) and below `ARRIVED_SPEED`.
const ARRIVED_DISTANCE: f64 = 0.02;
/// Speed (m/s) below which an arrived robot counts as stopped.
const ARRIVED_SPEED: f64 = 0.05;
/// Standard deviation of the mocap position noise on published states (m).
const POSITION_NOISE: f64 = 0.001;
/// Standard deviation of the velocity-estimate noise (m/s).
const VELOCITY_NOISE: f64 = 0.005;
/// Standard deviation of the unmodelled acceleration disturbance, drawn per
/// robot once per control period (m/s^2).
const DISTURBANCE: f64 = 0.2;

/// Run simulated robots against a running daemon.
#[derive(Debug, Args)]
pub struct SimArgs {
    #[command(flatten)]
    pub daemon: DaemonArgs,
    /// Team to simulate (default: the configuration's first).
    #[arg(long)]
    pub team: Option<String>,
    /// Seconds to run after the daemon first answers.
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    /// Control and state-publishing rate (Hz).
    #[arg(long, default_value_t = 50.0)]
    pub rate_hz: f64,
    /// Seed of the start positions and of every goal set.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Give up if no plan arrives within this many seconds of starting.
    #[arg(long, default_value_t = 20.0)]
    pub connect_timeout: f64,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// What a simulation run saw.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct SimReport {
    /// Seconds simulated (after the first plan).
    pub seconds: f64,
    /// Control rate (Hz).
    pub rate_hz: f64,
    /// Robots.
    pub robots: usize,
    /// Snapshots published.
    pub snapshots: u64,
    /// Plans received.
    pub plans: u64,
    /// Plans that answered the newest snapshot published when they arrived.
    pub plans_answering_newest: u64,
    /// Snapshot timestamp to plan receipt, median (ms).
    pub latency_p50_ms: f64,
    /// 99th percentile (ms).
    pub latency_p99_ms: f64,
    /// Maximum (ms).
    pub latency_max_ms: f64,
    /// Plans with status ok.
    pub ok: u64,
    /// Plans warm-started from the previous one.
    pub warm: u64,
    /// Degraded plans.
    pub degraded: u64,
    /// Deadline misses.
    pub deadline_missed: u64,
    /// Rejected snapshots.
    pub rejected: u64,
    /// Stale-state reports.
    pub stale: u64,
    /// No-plan replies.
    pub no_plan: u64,
    /// Robot-robot contacts begun (pairs closer than two radii).
    pub collisions: u64,
    /// Closest robot-robot distance over two radii (1 = touching).
    pub min_scaled_distance: f64,
    /// Mean distance from the planned position (m).
    pub mean_tracking_error_m: f64,
    /// Largest distance from the planned position (m).
    pub max_tracking_error_m: f64,
    /// Goal sets reached by the whole team.
    pub goal_sets_reached: u64,
}

/// The simulated team.
struct Robots {
    team: Team,
    position: Vec<Vector3<f64>>,
    velocity: Vec<Vector3<f64>>,
    goal: Vec<Vector3<f64>>,
    touching: Vec<bool>,
    rng: ChaCha8Rng,
    disturbance: Vec<Vector3<f64>>,
}

impl Robots {
    /// Advances from `from_ns` to `to_ns` tracking `plan` (with its time
    /// origin); returns the mean and max tracking error at `to_ns`.
    fn step(
        &mut self,
        plan: Option<&(JointPlan, u64)>,
        from_ns: u64,
        to_ns: u64,
        report: &mut SimReport,
    ) -> (f64, f64) {
        let n = self.team.robots;
        let h = (to_ns - from_ns) as f64 * 1e-9 / SUBSTEPS as f64;
        let plan_time = |origin: u64, sub: usize| (from_ns as f64 - origin as f64) * 1e-9 + sub as f64 * h;
        let axes = self.team.dim.axes();
        for w in &mut self.disturbance {
            for a in 0..axes {
                w[a] = DISTURBANCE * self.rng.sample::<f64, _>(StandardNormal);
            }
        }
        for sub in 0..SUBSTEPS {
            let desired = plan.map(|(p, origin)| p.at(plan_time(*origin, sub)));
            for i in 0..n {
                let u = match &desired {
                    Some(d) => {
                        d[i].acceleration
                            + KP * (d[i].position - self.position[i])
                            + KD * (d[i].velocity - self.velocity[i])
                    }
                    None => -KD * self.velocity[i],
                };
                self.velocity[i] += (u + self.disturbance[i]) * h;
                self.position[i] += self.velocity[i] * h;
            }
            self.count_contacts(report);
        }
        let Some((p, origin)) = plan else {
            return (0.0, 0.0);
        };
        let desired = p.at(plan_time(*origin, SUBSTEPS));
        let errors = desired.iter().zip(&self.position).map(|(d, x)| (d.position - x).norm());
        errors.fold((0.0, 0.0_f64), |(sum, max), e| (sum + e / n as f64, max.max(e)))
    }

    fn count_contacts(&mut self, report: &mut SimReport) {
        let n = self.team.robots;
        let (a, b) = self.team.separation();
        let mut pair = 0;
        for i in 0..n {
            for j in i + 1..n {
                let d =
                    flowopt_planner::problem::scaled_norm(self.team.dim, &(self.position[i] - self.position[j]), a, b);
                report.min_scaled_distance = report.min_scaled_distance.min(d);
                let touching = d < 1.0;
                if touching && !self.touching[pair] {
                    report.collisions += 1;
                }
                self.touching[pair] = touching;
                pair += 1;
            }
        }
    }

    fn arrived(&self) -> bool {
        (0..self.team.robots).all(|i| {
            (self.position[i] - self.goal[i]).norm() < ARRIVED_DISTANCE && self.velocity[i].norm() < ARRIVED_SPEED
        })
    }

    /// Publishes the state as measured (with noise) at `at_ns`.
    fn publish(&mut self, states: &mut StatePublisher, at_ns: u64) -> Result<u64> {
        let axes = self.team.dim.axes();
        let n = self.team.robots;
        let mut noise = |sd: f64| {
            let mut v = Vector3::zeros();
            for a in 0..axes {
                v[a] = sd * self.rng.sample::<f64, _>(StandardNormal);
            }
            v
        };
        let starts = (0..n)
            .map(|i| StartState {
                position: self.position[i] + noise(POSITION_NOISE),
                velocity: self.velocity[i] + noise(VELOCITY_NOISE),
                acceleration: Vector3::zeros(),
            })
            .collect();
        let measured = Problem { team: self.team.clone(), starts, goals: self.goal.clone(), obstacles: Vec::new() };
        let mut written = Ok(());
        let sequence = states.publish_with(|s| {
            s.timestamp_ns = at_ns;
            written = s.write_problem(&measured);
        })?;
        written?;
        Ok(sequence)
    }
}

/// Latency statistics and counters of received plans.
struct Receiver {
    latency_us: Histogram<u64>,
    newest_published: u64,
    answered: u64,
    current: Option<(JointPlan, u64)>,
}

impl Receiver {
    fn take(&mut self, msg: &JointTrajectory, team: &Team, report: &mut SimReport) {
        report.plans += 1;
        match msg.status {
            PlanStatus::Ok => report.ok += 1,
            PlanStatus::Degraded => report.degraded += 1,
            PlanStatus::DeadlineMissed => report.deadline_missed += 1,
            PlanStatus::RejectedInput => report.rejected += 1,
            PlanStatus::Stale => report.stale += 1,
            PlanStatus::NoPlan => report.no_plan += 1,
        }
        if msg.status == PlanStatus::Stale {
            return;
        }
        report.warm += u64::from(msg.warm_started);
        let latency = monotonic_ns().saturating_sub(msg.state_timestamp_ns) / 1000;
        let _ = self.latency_us.record(latency.max(1));
        if msg.answers_sequence == self.newest_published {
            report.plans_answering_newest += 1;
        }
        if msg.status.has_plan()
            && msg.fits(team)
            && msg.answers_sequence >= self.answered
            && let Ok(plan) = msg.plan()
        {
            self.answered = msg.answers_sequence;
            self.current = Some((plan, msg.state_timestamp_ns));
        }
    }
}

/// Runs `flowopt sim`.
pub fn run(args: SimArgs) -> Result<()> {
    let report = simulate(&args)?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_report(&report);
    }
    Ok(())
}

/// Prints a report for people.
pub fn print_report(r: &SimReport) {
    println!(
        "{} robots, {:.0} s at {:.0} Hz: {} snapshots, {} plans",
        r.robots, r.seconds, r.rate_hz, r.snapshots, r.plans
    );
    println!(
        "plans            ok {}, warm {}, degraded {}, deadline missed {}, rejected {}, stale {}, no plan {}",
        r.ok, r.warm, r.degraded, r.deadline_missed, r.rejected, r.stale, r.no_plan
    );
    println!("answering newest {} of {}", r.plans_answering_newest, r.plans);
    println!(
        "state-to-plan    p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
        r.latency_p50_ms, r.latency_p99_ms, r.latency_max_ms
    );
    println!("collisions       {} (closest approach {:.3} of the separation)", r.collisions, r.min_scaled_distance);
    println!("tracking error   mean {:.4} m, max {:.4} m", r.mean_tracking_error_m, r.max_tracking_error_m);
    println!("goal sets        {} reached", r.goal_sets_reached);
}

fn simulate(args: &SimArgs) -> Result<SimReport> {
    if !(args.rate_hz > 0.0 && args.seconds >= 0.0) {
        bail!("--rate-hz must be positive and --seconds not negative");
    }
    let (config, team_config) = args.daemon.team(args.team.as_deref())?;
    let team = team_config.team()?;
    let scenario = RandomScenario::new(team.clone());
    let first = scenario.generate(args.seed).context("drawing the start positions")?;
    let n = team.robots;
    let mut robots = Robots {
        team: team.clone(),
        position: first.starts.iter().map(|s| s.position).collect(),
        velocity: vec![Vector3::zeros(); n],
        goal: first.goals.clone(),
        touching: vec![false; n * (n - 1) / 2],
        rng: ChaCha8Rng::seed_from_u64(args.seed),
        disturbance: vec![Vector3::zeros(); n],
    };
    let channel = TeamChannel::new(&config.ipc.prefix, &team_config.name)?;
    let endpoint = Endpoint::new("flowopt-sim")?;
    let mut states = endpoint.state_publisher(&channel)?;
    let plans = endpoint.plan_subscriber(&channel)?;
    let mut report =
        SimReport { rate_hz: args.rate_hz, robots: n, min_scaled_distance: f64::INFINITY, ..SimReport::default() };
    let mut receiver = Receiver {
        latency_us: Histogram::new_with_bounds(1, 60_000_000, 3)?,
        newest_published: 0,
        answered: 0,
        current: None,
    };
    let period = Duration::from_secs_f64(1.0 / args.rate_hz);

    // Connect: publish the initial state until the daemon answers.
    let connect_deadline = Instant::now() + Duration::from_secs_f64(args.connect_timeout);
    loop {
        receiver.newest_published = robots.publish(&mut states, monotonic_ns())?;
        if let Some(msg) = plans.wait(period)? {
            let mut ignored = SimReport::default();
            receiver.take(&msg, &team, &mut ignored);
            break;
        }
        if Instant::now() > connect_deadline {
            bail!(
                "no plan on {}/{}/plan within {} s: is the daemon running?",
                config.ipc.prefix,
                team_config.name,
                args.connect_timeout
            );
        }
    }

    let started = Instant::now();
    let mut next = started;
    let mut simulated_ns = monotonic_ns();
    let (mut error_sum, mut error_ticks) = (0.0, 0u64);
    let mut goal_round = 0;
    while started.elapsed().as_secs_f64() < args.seconds {
        loop {
            let now = Instant::now();
            if now >= next {
                break;
            }
            if let Some(msg) = plans.wait(next - now)? {
                receiver.take(&msg, &team, &mut report);
            }
        }
        // Physics catches up with the wall clock, then the state is measured.
        let now_ns = monotonic_ns();
        let (mean, max) = robots.step(receiver.current.as_ref(), simulated_ns, now_ns, &mut report);
        simulated_ns = now_ns;
        if receiver.current.is_some() {
            error_sum += mean;
            error_ticks += 1;
            report.max_tracking_error_m = report.max_tracking_error_m.max(max);
        }
        if robots.arrived() {
            report.goal_sets_reached += 1;
            goal_round += 1;
            let fresh = scenario.generate(args.seed.wrapping_add(goal_round)).context("drawing new goals")?;
            robots.goal = fresh.goals;
        }
        receiver.newest_published = robots.publish(&mut states, now_ns)?;
        report.snapshots += 1;
        next += period;
        let now = Instant::now();
        if next + period < now {
            next = now;
        }
    }
    report.seconds = started.elapsed().as_secs_f64();
    report.mean_tracking_error_m = if error_ticks > 0 { error_sum / error_ticks as f64 } else { 0.0 };
    let h = &receiver.latency_us;
    if !h.is_empty() {
        report.latency_p50_ms = h.value_at_quantile(0.5) as f64 * 1e-3;
        report.latency_p99_ms = h.value_at_quantile(0.99) as f64 * 1e-3;
        report.latency_max_ms = h.max() as f64 * 1e-3;
    }
    Ok(report)
}
