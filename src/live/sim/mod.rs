//! `flowopt sim`: simulated mocap and controllers. A team of
//! double-integrator robots follows what the followability contract says
//! (the client library's [`flowopt_client::PlanSubscriber::to_follow`]:
//! a verified trajectory, or none, and then they brake) with a PD
//! controller plus the trajectory's acceleration as feedforward, and
//! publishes its measured state at the control rate. When every robot has
//! reached its goal, the team gets new goals. The published states carry
//! mocap noise and the robots an unmodelled acceleration disturbance
//! (seeded), so tracking is imperfect as on real robots.
//!
//! Every trajectory the contract says to follow is checked independently
//! of the daemon ([`check`]): collision-free on a dense grid (within the
//! success tolerance), starting where the robots are, and clear of the
//! obstacles reported in the snapshot it answers; a failure counts as
//! `followed_unverified`. With `--faults` the simulator injects the
//! controller-side faults of [`crate::live::faults::SCHEDULE`] (bad
//! snapshots, a restart, frozen robots, obstacles appearing and crossing
//! the team: [`world`]) and reports every fault's window separately.

mod check;
mod lab;
mod report;
mod robots;
mod stops;
mod tally;
mod world;

use std::collections::{HashMap, VecDeque};
use std::io::Write;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use flowopt_client::clock::monotonic_ns;
use flowopt_client::{
    Endpoint, Followed, JointTrajectory, PlanStatus, PlanSubscriber, Reason, StatePublisher, TeamChannel,
};
use flowopt_daemon::config::{DaemonConfig, TeamConfig};
use flowopt_planner::problem::{Obstacle, Problem, Team};
use flowopt_planner::scenario::RandomScenario;
use hdrhistogram::Histogram;
use tracing::warn;

use crate::live::daemon_args::DaemonArgs;
use crate::live::faults::{Fault, SCHEDULE, Scheduled};
use crate::live::observe::{ObserveArgs, Observer, Watched};
use check::{Failure, check};
use lab::Lab;
pub use lab::LabArgs;
use report::{CONTACTS_LOGGED, ContactEvent};
pub use report::{FaultReport, SimReport, print_report};
use robots::{Robots, Touch, Touched};
use stops::Stops;
pub use tally::Tally;
use world::{SimObstacle, World};

/// Snapshots whose reported obstacles are remembered, to check the plans
/// that answer them.
const REMEMBERED: usize = 256;

/// Run simulated robots against a running daemon.
#[derive(Debug, Args)]
pub struct SimArgs {
    #[command(flatten)]
    pub daemon: DaemonArgs,
    #[command(flatten)]
    pub observe: ObserveArgs,
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
    /// Inject the controller-side faults of the fault schedule and report
    /// each fault's window (prints a `{"ready":true}` line when the run
    /// starts, for the demo to time its own faults by).
    #[arg(long)]
    pub faults: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
    #[command(flatten)]
    pub lab: LabArgs,
}

/// Runs `flowopt sim`.
pub fn run(args: SimArgs) -> Result<()> {
    let (config, team_config) = args.daemon.team(args.team.as_deref())?;
    let watched = [Watched::new(&team_config.name, &team_config.team()?)];
    let observer = Observer::start(&args.observe, &config.ipc.prefix, &watched)?;
    let report = simulate(&args, &config, &team_config);
    if let Some(observer) = observer {
        observer.finish()?;
    }
    let report = report?;
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_report(&report);
    }
    Ok(())
}

/// A controller process's ports (dropped and recreated by a restart).
struct Controller {
    _endpoint: Endpoint,
    states: StatePublisher,
    plans: PlanSubscriber,
}

impl Controller {
    fn open(channel: &TeamChannel) -> Result<Self> {
        let endpoint = Endpoint::new("flowopt-sim")?;
        let states = endpoint.state_publisher(channel)?;
        let plans = endpoint.plan_subscriber(channel, &states)?;
        Ok(Self { _endpoint: endpoint, states, plans })
    }
}

/// How far back (s) a contact's report lists the answers before it.
const RECENT_S: f64 = 0.5;

/// The run's counters: the whole run and every fault window.
struct Counters {
    overall: Tally,
    windows: Vec<(Scheduled, Tally)>,
    latency_us: Histogram<u64>,
    warm: u64,
    answering_newest: u64,
    /// Injected snapshots: sequence -> (window, expected reason).
    expected: HashMap<u64, (usize, Reason)>,
    /// The daemon's deadline (ms).
    deadline_ms: f64,
    /// The answers of the last [`RECENT_S`]: when (s into the run), status
    /// and reason; the newest last.
    recent: VecDeque<(f64, String)>,
    /// When the newest `Ok` answer came (s into the run).
    last_ok_s: Option<f64>,
}

impl Counters {
    /// Applies `f` to the overall tally and to every window covering `t`.
    fn each(&mut self, t: f64, mut f: impl FnMut(&mut Tally)) {
        f(&mut self.overall);
        for (w, tally) in &mut self.windows {
            if w.covers(t) {
                f(tally);
            }
        }
    }

    /// Counts a received message at `t` s into the run.
    fn message(&mut self, msg: &JointTrajectory, t: f64, newest: u64, since_ns: u64) {
        // Statuses and reasons as docs/MESSAGES.md names them.
        let status = match msg.status() {
            Ok(s) => format!("{s:?}"),
            Err(_) => "unreadable".into(),
        };
        let status = status.as_str();
        let reason = match msg.reason() {
            Ok(Reason::None) => None,
            Ok(r) => Some(format!("{r:?}")),
            Err(_) => Some("unreadable".into()),
        };
        self.each(t, |tally| tally.message(status, reason.as_deref()));
        while self.recent.front().is_some_and(|(at, _)| *at < t - RECENT_S) {
            self.recent.pop_front();
        }
        self.recent.push_back((t, reason.as_ref().map_or_else(|| status.to_string(), |r| format!("{status} {r}"))));
        if msg.status() == Ok(PlanStatus::Ok) {
            self.last_ok_s = Some(t);
        }
        if msg.status() == Ok(PlanStatus::NoPlan) {
            warn!(sequence = msg.answers_sequence, reason = ?msg.reason(), timings = ?msg.timings, "no plan");
        }
        if msg.status() == Ok(PlanStatus::Ok) && msg.warm_started == 1 {
            self.warm += 1;
        }
        if msg.state_timestamp_ns >= since_ns && msg.state_timestamp_ns > 0 {
            let latency = monotonic_ns().saturating_sub(msg.state_timestamp_ns) / 1000;
            let _ = self.latency_us.record(latency.max(1));
        }
        if msg.answers_sequence == newest {
            self.answering_newest += 1;
        }
        if msg.published_ns >= msg.received_ns && msg.received_ns > 0 {
            let ms = (msg.published_ns - msg.received_ns) as f64 * 1e-6;
            let deadline = self.deadline_ms;
            if ms > deadline {
                warn!(sequence = msg.answers_sequence, timings = ?msg.timings, "answer published {ms:.2} ms after its snapshot's arrival, past the {deadline} ms deadline");
            }
            self.each(t, |tally| tally.answered_in(ms, deadline));
        }
        if let Some((window, expected)) = self.expected.remove(&msg.answers_sequence)
            && msg.reason() == Ok(expected)
        {
            self.overall.rejected_as_expected += 1;
            self.windows[window].1.rejected_as_expected += 1;
        }
    }
}

/// The snapshots a run published: what each reported, to check the plans
/// that answer them against.
#[derive(Default)]
struct Reported {
    /// `(sequence, timestamp, obstacles)`, oldest first.
    snapshots: VecDeque<(u64, u64, Vec<Obstacle>)>,
}

impl Reported {
    fn push(&mut self, sequence: u64, timestamp_ns: u64, obstacles: Vec<Obstacle>) {
        if self.snapshots.len() == REMEMBERED {
            self.snapshots.pop_front();
        }
        self.snapshots.push_back((sequence, timestamp_ns, obstacles));
    }

    /// What the newest good snapshot at or before `sequence` reported (a
    /// rejected one is answered by the plan checked against the one before).
    fn answered_by(&self, sequence: u64) -> Option<(u64, &[Obstacle])> {
        self.snapshots.iter().rev().find(|(s, _, _)| *s <= sequence).map(|(_, t, o)| (*t, o.as_slice()))
    }

    /// Forgets every snapshot (a restarted controller counts sequences
    /// from 1 again).
    fn clear(&mut self) {
        self.snapshots.clear();
    }
}

fn simulate(args: &SimArgs, config: &DaemonConfig, team_config: &TeamConfig) -> Result<SimReport> {
    if !(args.rate_hz > 0.0 && args.seconds >= 0.0) {
        bail!("--rate-hz must be positive and --seconds not negative");
    }
    let day = args.lab.day();
    day.check().map_err(anyhow::Error::msg)?;
    let team = team_config.team()?;
    // The braking bound of the plans the check reads (the goal and the
    // stopping horizons), solved before the first tick: solved on first
    // use, its linear programs (3-23 ms each) stalled control periods by
    // up to 246 ms.
    if let Some(a) = team.max_acceleration {
        for horizon in std::iter::once(team.horizon).chain(team_config.stop_horizons()) {
            flowopt_planner::braking::prepare(team.degree, team.samples, horizon, a);
        }
    }
    // The check holds plans to the daemon's bounds: the table alone, no
    // program per start (`braking::past_side_with_goal`) inside it.
    flowopt_planner::braking::solve_in_background(|| {});
    // The contract's check of a followable answer: moving obstacles over
    // the daemon's shorter check window.
    let checked = Team { obstacle_prediction: Some(team_config.obstacle_check_s()), ..team.clone() };
    let scenario = RandomScenario::new(team.clone());
    let first = scenario.generate(args.seed).context("drawing the start positions")?;
    let mut robots = Robots::new(&first, args.seed);
    let mut lab = (!day.is_quiet()).then(|| Lab::new(day, team.robots, args.seed));
    robots.lag_ns = lab.as_ref().map_or(0, Lab::lag_ns);
    let channel = TeamChannel::new(&config.ipc.prefix, &team_config.name)?;
    let mut controller = Some(Controller::open(&channel)?);
    let period = Duration::from_secs_f64(1.0 / args.rate_hz);
    let mut world = World::default();
    let mut reported = Reported::default();

    // Connect: publish the initial state until the daemon answers.
    let connect_deadline = Instant::now() + Duration::from_secs_f64(args.connect_timeout);
    let mut newest;
    loop {
        let c = controller.as_mut().context("the controller is open")?;
        let measured = robots.measured(Vec::new());
        newest = publish(&mut c.states, &measured, monotonic_ns(), |_| {})?;
        if c.plans.wait(period)?.is_some() {
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
    if args.faults {
        println!("{{\"ready\":true}}");
        std::io::stdout().flush()?;
    }

    let schedule: Vec<Scheduled> = if args.faults { SCHEDULE.to_vec() } else { Vec::new() };
    let mut counters = Counters {
        overall: Tally::default(),
        windows: schedule.iter().map(|s| (*s, Tally::default())).collect(),
        latency_us: Histogram::new_with_bounds(1, 60_000_000, 3)?,
        warm: 0,
        answering_newest: 0,
        expected: HashMap::new(),
        deadline_ms: team_config.deadline_ms,
        recent: VecDeque::new(),
        last_ok_s: None,
    };
    let mut done = vec![false; schedule.len()];
    let mut report = SimReport { rate_hz: args.rate_hz, robots: team.robots, ..SimReport::default() };
    let started = Instant::now();
    let mut since_ns = monotonic_ns();
    let mut next = started;
    let mut simulated_ns = since_ns;
    let (mut error_sum, mut error_ticks) = (0.0, 0u64);
    let mut goal_round = 0;
    let mut followed_key = None;
    let mut answered = None;
    let mut without_since: Option<f64> = None;
    let mut restart_at: Option<f64> = None;
    let mut obstacles_then = Vec::new();
    let mut stops = Stops::default();
    while started.elapsed().as_secs_f64() < args.seconds {
        // Messages until the next tick.
        loop {
            let now = Instant::now();
            if now >= next {
                break;
            }
            let Some(c) = controller.as_mut() else {
                std::thread::sleep(next - now);
                break;
            };
            if let Some(msg) = c.plans.wait(next - now)? {
                let t = started.elapsed().as_secs_f64();
                counters.message(&msg, t, newest, since_ns);
                answered = Some(msg.answers_sequence);
            }
        }
        let t = started.elapsed().as_secs_f64();
        let now_ns = monotonic_ns();
        // What the contract says to follow, checked on every message that
        // says to follow something.
        let followed = controller.as_ref().and_then(|c| c.plans.to_follow()).cloned();
        let key = followed.as_ref().map(|f| (f.plan_sequence, f.origin_ns, f.status, answered));
        if key.is_some() && key != followed_key {
            let f = followed.as_ref().context("a followed plan")?;
            let (reported_ns, obstacles) = answered.and_then(|a| reported.answered_by(a)).unwrap_or((0, &[]));
            let checking = Instant::now();
            let checked_plan = check(&checked, f, &robots.position, simulated_ns, obstacles, reported_ns);
            report.check_max_ms = report.check_max_ms.max(checking.elapsed().as_secs_f64() * 1e3);
            if let Err(failure) = checked_plan {
                warn!(status = ?f.status, plan_sequence = f.plan_sequence, "followed a plan that fails the check: {failure:?}");
                let through = matches!(failure, Failure::ThroughObstacle(_));
                counters.each(t, |tally| {
                    tally.followed_unverified += 1;
                    tally.followed_through_obstacle += u64::from(through);
                });
            }
        }
        followed_key = key;
        match (&followed, without_since) {
            (None, None) => without_since = Some(t),
            (Some(_), Some(since)) => {
                counters.each(since, |tally| tally.without_plan((t - since) * 1e3));
                counters.each(t, |tally| tally.without_plan((t - since) * 1e3));
                without_since = None;
            }
            _ => {}
        }
        // Physics catches up with the wall clock, then the state is measured.
        let frozen = schedule.iter().any(|s| s.fault == Fault::Frozen && t >= s.at_s && t < s.at_s + s.lasts_s);
        let period_s = (now_ns - simulated_ns) as f64 * 1e-9;
        let obstacles_now = world.present(t - period_s);
        if obstacles_now.len() != obstacles_then.len() {
            robots.obstacles_changed();
        }
        let motion = robots.step(followed.as_ref(), frozen, simulated_ns, now_ns, &obstacles_now);
        for touch in motion.began.iter().take(CONTACTS_LOGGED.saturating_sub(report.contact_log.len())) {
            report.contact_log.push(contact_event(
                touch,
                t - now_ns.saturating_sub(touch.at_ns) as f64 * 1e-9,
                followed.as_ref(),
                &counters,
            ));
        }
        obstacles_then = obstacles_now;
        simulated_ns = now_ns;
        counters.each(t, |tally| {
            tally.motion(motion.closest, motion.contacts(), motion.closest_obstacle, motion.obstacle_contacts());
            tally.workspace_excess_m = tally.workspace_excess_m.max(motion.workspace_excess);
        });
        if let Some(ended) = stops.tick(t, followed.as_ref(), robots.at_rest(), robots.arrived()) {
            counters.each(ended.since_s, |tally| tally.stop(&ended));
        }
        if followed.is_some() && !frozen {
            error_sum += motion.tracking.0;
            error_ticks += 1;
            report.max_tracking_error_m = report.max_tracking_error_m.max(motion.tracking.1);
        }
        if let Some(lab) = lab.as_mut() {
            lab.tick(t, period_s, &mut robots, &mut world);
        }
        if robots.arrived() {
            report.goal_sets_reached += 1;
            robots.goal = new_goals(&scenario, args.seed, &mut goal_round, &world, t)?;
            lab.iter_mut().for_each(Lab::new_goal_set);
        }
        // Controller-side faults due now.
        for (k, s) in schedule.iter().enumerate() {
            if done[k] || t < s.at_s || s.fault.in_demo() {
                continue;
            }
            match s.fault {
                Fault::ControllerRestart => {
                    controller = None;
                    restart_at = Some(t + s.lasts_s);
                }
                Fault::Frozen => {}
                Fault::ObstacleAppears => {
                    // Ahead of a moving robot on the plan it follows; tried
                    // every tick until one moves.
                    let Some(f) = followed.as_ref() else { continue };
                    let Some(at) = world::ahead_of_moving(f, now_ns, &robots.position, &robots.velocity, &robots.goal)
                    else {
                        continue;
                    };
                    world.add(SimObstacle {
                        position: at,
                        velocity: Default::default(),
                        from_s: t,
                        until_s: t + s.lasts_s,
                    });
                    count_injected(&mut counters, k);
                }
                Fault::ObstacleCrossing => {
                    let centre = robots.position.iter().sum::<nalgebra::Vector3<f64>>() / team.robots as f64;
                    world.add(world::crossing(&team, centre, t));
                    count_injected(&mut counters, k);
                }
                fault => {
                    let Some(c) = controller.as_mut() else { continue };
                    let measured = robots.measured(world.present(t));
                    let sequence = publish(&mut c.states, &measured, now_ns, |snapshot| match fault {
                        Fault::SpeedGlitch => snapshot.robot[0].velocity = [1e6, 0.0, 0.0],
                        Fault::NanState => snapshot.robot[0].position[0] = f64::NAN,
                        Fault::ZeroTimestamp => snapshot.timestamp_ns = 0,
                        _ => snapshot.timestamp_ns = now_ns + 3_600_000_000_000,
                    })?;
                    if let Some(reason) = fault.expected_rejection() {
                        counters.expected.insert(sequence, (k, reason));
                        count_injected(&mut counters, k);
                    }
                    // Give the answer to the bad snapshot a moment to arrive.
                    if let Some(msg) = c.plans.wait(period / 2)? {
                        counters.message(&msg, t, sequence, since_ns);
                        answered = Some(msg.answers_sequence);
                    }
                }
            }
            done[k] = true;
        }
        if restart_at.is_some_and(|at| t >= at) {
            controller = Some(Controller::open(&channel)?);
            since_ns = monotonic_ns();
            reported.clear();
            answered = None;
            restart_at = None;
        }
        if let Some(c) = controller.as_mut() {
            let obstacles = world.present(t);
            let measured = robots.measured(obstacles.clone());
            let at_ns = monotonic_ns();
            newest = publish(&mut c.states, &measured, at_ns, |_| {})?;
            reported.push(newest, at_ns, obstacles);
            report.snapshots += 1;
        }
        next += period;
        let now = Instant::now();
        if next + period < now {
            next = now;
        }
    }
    let t = started.elapsed().as_secs_f64();
    if let Some(since) = without_since {
        counters.each(since, |tally| tally.without_plan((t - since) * 1e3));
    }
    if let Some(ended) = stops.end(t) {
        counters.each(ended.since_s, |tally| tally.stop(&ended));
    }
    report.seconds = t;
    report.lab = lab.map(|lab| lab.report(t));
    report.mean_tracking_error_m = if error_ticks > 0 { error_sum / error_ticks as f64 } else { 0.0 };
    let h = &counters.latency_us;
    if !h.is_empty() {
        report.latency_p50_ms = h.value_at_quantile(0.5) as f64 * 1e-3;
        report.latency_p99_ms = h.value_at_quantile(0.99) as f64 * 1e-3;
        report.latency_p999_ms = h.value_at_quantile(0.999) as f64 * 1e-3;
        report.latency_max_ms = h.max() as f64 * 1e-3;
    }
    report.warm = counters.warm;
    report.plans_answering_newest = counters.answering_newest;
    report.overall = counters.overall;
    report.faults = counters
        .windows
        .into_iter()
        .filter(|(s, _)| s.at_s < t)
        .map(|(s, tally)| FaultReport {
            fault: s.fault.name().to_string(),
            at_s: s.at_s,
            until_s: s.at_s + s.lasts_s + crate::live::faults::SETTLE_S,
            tally,
        })
        .collect();
    Ok(report)
}

/// Counts an injected fault in the run and in window `k`.
fn count_injected(counters: &mut Counters, k: usize) {
    counters.overall.injected += 1;
    counters.windows[k].1.injected += 1;
}

/// The team's next goals: the next seeded draw whose goals keep clear of
/// the obstacles present `t` s into the run.
fn new_goals(
    scenario: &RandomScenario,
    seed: u64,
    round: &mut u64,
    world: &World,
    t: f64,
) -> Result<Vec<nalgebra::Vector3<f64>>> {
    let clearance = scenario.team.robot.radius * 1.5;
    loop {
        *round += 1;
        let fresh = scenario.generate(seed.wrapping_add(*round)).context("drawing new goals")?;
        if fresh.goals.iter().all(|g| world.clear_of(t, g, clearance)) {
            return Ok(fresh.goals);
        }
    }
}

/// Publishes `measured`, stamped `at_ns`, changed by `edit`; returns its
/// sequence.
fn publish(
    states: &mut StatePublisher,
    measured: &Problem,
    at_ns: u64,
    edit: impl FnOnce(&mut flowopt_client::StateSnapshot),
) -> Result<u64> {
    let mut written = Ok(());
    let sequence = states.publish_with(|s| {
        s.timestamp_ns = at_ns;
        written = s.write_problem(measured);
        edit(s);
    })?;
    written?;
    Ok(sequence)
}

/// What a contact's report says: the contact, and what the team followed
/// and was last told when it began (`at_s` into the run).
fn contact_event(touch: &Touch, at_s: f64, followed: Option<&Followed>, counters: &Counters) -> ContactEvent {
    let (other_robot, obstacle) = match touch.other {
        Touched::Robot(j) => (Some(j), None),
        Touched::Obstacle(m) => (None, Some(m)),
    };
    ContactEvent {
        at_s,
        robot: touch.robot,
        other_robot,
        obstacle,
        speed_mps: touch.speed,
        other_speed_mps: touch.other_speed,
        position_m: touch.position.into(),
        other_position_m: touch.other_position.into(),
        following: followed.map(|f| format!("{:?}", f.status)),
        plan_age_ms: followed.map(|f| (touch.at_ns as f64 - f.origin_ns as f64) * 1e-6),
        last_answer: counters.recent.back().map(|(_, a)| a.clone()),
        since_ok_ms: counters.last_ok_s.map(|ok| (at_s - ok) * 1e3),
        answers_before: counters
            .recent
            .iter()
            .filter(|(t, _)| *t >= at_s - RECENT_S)
            .map(|(t, a)| ((at_s - t) * 1e3, a.clone()))
            .collect(),
    }
}
