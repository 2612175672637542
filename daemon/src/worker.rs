//! One team's worker thread: takes the newest snapshot, answers it,
//! publishes; publishes late cold plans as they are adopted; reports
//! silence. It owns its own iceoryx2 node and plan publisher (ports are not
//! `Send`) and is the only code that touches the wire: it turns snapshots
//! into problems ([`crate::convert`], [`crate::admission`]), hands them to
//! the team's planner and writes every reply with one function
//! ([`write_reply`]).

use std::time::{Duration, Instant};

use crossbeam::channel::{Receiver, Sender, select};
use flowopt_client::clock::monotonic_ns;
use flowopt_client::{
    Endpoint, JointTrajectory, PlanPublisher, PlanStatus, PortError, Reason, StageTimings, StateSnapshot, TeamChannel,
};
use tracing::{debug, info, info_span, warn};

use crate::admission::Admission;
use crate::answer::{Answer, Follow, Why};
use crate::config::TeamConfig;
use crate::convert::{Plausible, Rejection, check_header, measured};
use crate::held::Held;
use crate::metrics::TeamMetrics;
use crate::planning::TeamPlanner;
use flowopt_planner::method::Stages;

/// A snapshot handed from the WaitSet thread to a worker.
#[derive(Debug)]
pub(crate) struct Job {
    /// The snapshot, copied out of shared memory.
    pub snapshot: Box<StateSnapshot>,
    /// The iceoryx2 publisher that sent it.
    pub publisher: u128,
    /// When the daemon took it.
    pub received: Instant,
    /// The same, on the shared monotonic clock.
    pub received_ns: u64,
}

/// Runs until the job channel disconnects. Reports its start-up result on
/// `ready` before taking work.
pub(crate) fn run(
    config: TeamConfig,
    channel: TeamChannel,
    mut planner: TeamPlanner,
    jobs: Receiver<Job>,
    ready: Sender<Result<(), PortError>>,
    mut metrics: TeamMetrics,
) {
    let publisher = match Endpoint::new(&format!("flowopt-daemon-{}", config.name))
        .and_then(|endpoint| endpoint.plan_publisher(&channel).map(|p| (endpoint, p)))
    {
        Ok(pair) => {
            let _ = ready.send(Ok(()));
            pair
        }
        Err(e) => {
            let _ = ready.send(Err(e));
            return;
        }
    };
    let (_endpoint, publisher) = publisher;
    let stale_after = Duration::from_secs_f64(config.stale_after_ms * 1e-3);
    let skew = Duration::from_secs_f64(config.clock_skew_ms * 1e-3);
    let mut admission = Admission::new(stale_after.as_nanos() as u64, skew.as_nanos() as u64);
    let period = (config.replan_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / config.replan_hz));
    let cold_results = planner.cold_results();
    let mut last_job = Instant::now();
    let mut reported_stale = true;
    // When the newest accepted snapshot arrived (a late cold plan answers it).
    let mut newest_received_ns = 0;
    loop {
        // Until the next staleness check; once reported, a wake each
        // `stale_after` (a zero wait here spun the worker, under
        // SCHED_FIFO, on a whole core while no controller published).
        let wait = if reported_stale { stale_after } else { stale_after.saturating_sub(last_job.elapsed()) };
        select! {
            recv(jobs) -> job => {
                let Ok(job) = job else { break };
                reported_stale = false;
                last_job = Instant::now();
                answer(&config, &mut planner, &mut admission, &publisher, &job, &mut metrics);
                if planner.newest().is_some_and(|(sequence, _)| sequence == job.snapshot.sequence) {
                    newest_received_ns = job.received_ns;
                }
                if let Some(period) = period {
                    std::thread::sleep(period.saturating_sub(last_job.elapsed()));
                }
            }
            recv(cold_results) -> result => {
                let Ok(result) = result else { continue };
                let answered = planner.newest();
                if let (Some(answer), Some((sequence, timestamp))) = (planner.on_cold(result), answered) {
                    let reply =
                        Reply::of(&answer, planner.held(), sequence, timestamp, newest_received_ns, StageTimings::default());
                    publish(&publisher, &reply, sequence, &mut metrics);
                    if let Some(by) = answer.by {
                        metrics.won(by);
                    }
                }
            }
            default(wait) => {
                if !reported_stale && last_job.elapsed() >= stale_after {
                    let (sequence, timestamp) = planner.newest().unwrap_or((0, 0));
                    warn!(team = config.name, sequence, "no snapshot for {stale_after:?}: state is stale");
                    let now = monotonic_ns();
                    let follow = planner.reissue(now);
                    let held = planner.held().filter(|_| follow == Follow::Held);
                    let reply = Reply::held(held, Reason::StaleState, u32::MAX, sequence, timestamp, now);
                    publish(&publisher, &reply, sequence, &mut metrics);
                    reported_stale = true;
                }
            }
        }
    }
    info!(team = config.name, "worker stopped");
}

/// What became of one snapshot.
#[derive(Debug)]
enum Outcome {
    /// Planned: the planner's answer, and the robot its plans move out of
    /// a contact ([`crate::convert::Measured::recovering`]).
    Planned(Answer, Option<usize>),
    /// A measurement whose task was rejected: the planner's answer in its
    /// world, reported with the rejection.
    Task(Answer, Rejection),
    /// Not a measurement: what is followed now.
    Rejected(Rejection, Follow),
}

/// Checks the snapshot of `job` in the documented order (header, clock and
/// sequence, values, task; [`crate::convert`]) and answers it.
fn respond(
    config: &TeamConfig,
    planner: &mut TeamPlanner,
    admission: &mut Admission,
    job: &Job,
) -> (Outcome, StageTimings) {
    let s = &job.snapshot;
    let t = Instant::now();
    let checked = {
        let _span = info_span!("validate").entered();
        let plausible = Plausible {
            robot_speed: config.implausible_factor * config.max_speed,
            obstacle_speed: config.max_obstacle_speed,
        };
        check_header(s, planner.team(), &config.name, config.max_obstacles)
            .and_then(|()| admission.check(job.publisher, s.sequence, s.timestamp_ns, job.received_ns))
            .and_then(|()| measured(s, planner.team(), plausible))
    };
    let mut timings = StageTimings { validate_us: us(t.elapsed()), ..StageTimings::default() };
    let measured = match checked {
        Ok(m) => m,
        Err(rejection) => return (Outcome::Rejected(rejection, planner.reissue(job.received_ns)), timings),
    };
    admission.accept(job.publisher, s.sequence);
    let deadline = job.received + planner.deadline();
    let outcome = match measured.task {
        Ok(()) => Outcome::Planned(
            planner.answer(measured.problem, s.timestamp_ns, s.sequence, deadline),
            measured.recovering,
        ),
        Err(rejection) => {
            Outcome::Task(planner.observe(measured.problem, s.timestamp_ns, s.sequence, deadline), rejection)
        }
    };
    if let Outcome::Planned(answer, _) | Outcome::Task(answer, _) = &outcome {
        stage_timings(&mut timings, &answer.stages);
    }
    (outcome, timings)
}

fn answer(
    config: &TeamConfig,
    planner: &mut TeamPlanner,
    admission: &mut Admission,
    publisher: &PlanPublisher,
    job: &Job,
    metrics: &mut TeamMetrics,
) {
    let s = &job.snapshot;
    let span = info_span!("plan", sequence = s.sequence);
    let _entered = span.enter();
    let queue = job.received.elapsed();
    let (sequence, timestamp) = (s.sequence, s.timestamp_ns);
    let (outcome, timings) = respond(config, planner, admission, job);
    let mut reply = match &outcome {
        Outcome::Planned(answer, recovering) => {
            debug!(sequence, follow = ?answer.follow, why = ?answer.why, iterations = answer.iterations, "answered");
            let mut reply = Reply::of(answer, planner.held(), sequence, timestamp, job.received_ns, timings);
            if let Some(robot) = recovering.filter(|_| reply.status == PlanStatus::Ok && reply.reason == Reason::None) {
                // The plan moves the robot out of the contact it was measured in.
                (reply.reason, reply.reason_index) = (Reason::Recovering, robot as u32);
            }
            reply
        }
        Outcome::Task(answer, rejection) => {
            warn!(sequence, reason = ?rejection.reason, index = rejection.index, follow = ?answer.follow, "task rejected");
            let mut reply = Reply::of(answer, planner.held(), sequence, timestamp, job.received_ns, timings);
            reply.reason = rejection.reason;
            reply.reason_index = rejection.index;
            reply
        }
        Outcome::Rejected(rejection, follow) => {
            warn!(sequence, reason = ?rejection.reason, index = rejection.index, "snapshot rejected");
            let held = planner.held().filter(|_| *follow == Follow::Held);
            let mut reply = Reply::held(held, rejection.reason, rejection.index, sequence, timestamp, job.received_ns);
            reply.timings = timings;
            reply
        }
    };
    reply.timings.queue_us = us(queue);
    let _publish = info_span!("publish").entered();
    reply.timings.total_us = us(job.received.elapsed());
    publish(publisher, &reply, sequence, metrics);
    metrics.latency(job.received.elapsed(), planner.deadline());
    if let Outcome::Planned(Answer { by: Some(by), .. }, _) = &outcome {
        metrics.won(by);
    }
}

/// Publishes `reply` (to snapshot `sequence`) and counts it.
fn publish(publisher: &PlanPublisher, reply: &Reply<'_>, sequence: u64, metrics: &mut TeamMetrics) {
    if let Err(e) = publisher.publish_with(|msg| write_reply(msg, reply)) {
        warn!(sequence, "cannot publish the reply: {e}");
        return;
    }
    metrics.answered(reply.status, reply.reason);
}

/// Everything one plan message says.
#[derive(Debug)]
struct Reply<'a> {
    status: PlanStatus,
    reason: Reason,
    reason_index: u32,
    /// The trajectory to follow (for the followable statuses).
    plan: Option<&'a Held>,
    answers_sequence: u64,
    state_timestamp_ns: u64,
    received_ns: u64,
    iterations: usize,
    warm_started: bool,
    candidates: usize,
    timings: StageTimings,
}

impl<'a> Reply<'a> {
    /// The reply carrying `answer` to snapshot `sequence` (measured at
    /// `timestamp_ns`); `held` is the planner's held plan after it.
    fn of(
        answer: &Answer,
        held: Option<&'a Held>,
        sequence: u64,
        timestamp_ns: u64,
        received_ns: u64,
        timings: StageTimings,
    ) -> Self {
        let status = match (answer.follow, held) {
            (Follow::New, Some(_)) => PlanStatus::Ok,
            (Follow::Held, Some(_)) => PlanStatus::Held,
            (Follow::Stopping, Some(_)) => PlanStatus::Stopping,
            _ => PlanStatus::NoPlan,
        };
        Reply {
            status,
            reason: reason_of(answer.why),
            reason_index: u32::MAX,
            plan: held.filter(|_| status.followable()),
            answers_sequence: sequence,
            state_timestamp_ns: timestamp_ns,
            received_ns,
            iterations: answer.iterations,
            warm_started: answer.warm,
            candidates: answer.candidates,
            timings,
        }
    }

    /// The held plan re-issued (or no plan, when there is none) for
    /// `reason`: a rejected snapshot, or silence.
    fn held(
        held: Option<&'a Held>,
        reason: Reason,
        reason_index: u32,
        sequence: u64,
        timestamp_ns: u64,
        received_ns: u64,
    ) -> Self {
        Reply {
            status: if held.is_some() { PlanStatus::Held } else { PlanStatus::NoPlan },
            reason,
            reason_index,
            plan: held,
            answers_sequence: sequence,
            state_timestamp_ns: timestamp_ns,
            received_ns,
            iterations: 0,
            warm_started: false,
            candidates: 0,
            timings: StageTimings::default(),
        }
    }
}

/// The wire reason of a planner's `why`.
fn reason_of(why: Why) -> Reason {
    match why {
        Why::None => Reason::None,
        Why::DeadlineMissed => Reason::DeadlineMissed,
        Why::NotVerified => Reason::NotVerified,
        Why::NotFollowing => Reason::NotFollowing,
        Why::Limits => Reason::Limits,
        Why::WorldChanged => Reason::WorldChanged,
    }
}

/// Writes every field of a reply but those the publisher stamps (`version`,
/// `team`, `published_ns`). A plan the message cannot carry (the
/// configuration was checked against the capacity) becomes `NoPlan`.
fn write_reply(msg: &mut JointTrajectory, reply: &Reply<'_>) {
    msg.set_status(reply.status);
    msg.set_reason(reply.reason);
    msg.reason_index = reply.reason_index;
    msg.answers_sequence = reply.answers_sequence;
    msg.state_timestamp_ns = reply.state_timestamp_ns;
    msg.received_ns = reply.received_ns;
    msg.iterations = reply.iterations.min(u32::MAX as usize) as u32;
    msg.warm_started = u32::from(reply.warm_started);
    msg.candidates = reply.candidates.min(u32::MAX as usize) as u32;
    msg.timings = reply.timings;
    match reply.plan {
        Some(held) if msg.write_plan(&held.plan).is_ok() => {
            msg.plan_sequence = held.sequence;
            msg.plan_origin_ns = held.origin_ns;
            msg.primal_residual = held.primal;
            msg.smoothness = held.smoothness;
            msg.max_speed = held.max_speed;
            msg.max_acceleration = held.max_acceleration;
        }
        Some(_) => {
            msg.set_status(PlanStatus::NoPlan);
            msg.set_reason(Reason::Solver);
        }
        None => {
            msg.primal_residual = f64::NAN;
            msg.smoothness = f64::NAN;
        }
    }
}

/// The wire timings of `stages`, into `timings`.
fn stage_timings(timings: &mut StageTimings, stages: &Stages) {
    timings.warm_start_us = us(stages.warm_start);
    timings.sample_us = us(stages.sample);
    timings.rank_us = us(stages.rank);
    timings.init_us = us(stages.init);
    timings.filter_us = us(stages.filter);
    timings.optimise_us = us(stages.optimise);
    timings.select_us = us(stages.select);
}

/// Microseconds, saturating at `u32::MAX`.
fn us(d: Duration) -> u32 {
    d.as_micros().min(u32::MAX as u128) as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::Problem;
    use flowopt_planner::scenario::RandomScenario;

    fn config() -> TeamConfig {
        toml::from_str(
            "name = \"t\"\ndim = 2\nrobots = 4\nrobot = { radius = 0.1 }\n\
             workspace = { min = [-1.0, -1.0], max = [1.0, 1.0] }\nmax_obstacles = 2\ndeadline_ms = 1000.0\n",
        )
        .unwrap()
    }

    fn admission() -> Admission {
        Admission::new(500_000_000, 50_000_000)
    }

    /// A job for snapshot `sequence` of `problem` from publisher 1, measured now.
    fn job(problem: &Problem, sequence: u64, edit: impl FnOnce(&mut StateSnapshot)) -> Job {
        let mut s = StateSnapshot::new();
        s.set_team("t").unwrap();
        s.sequence = sequence;
        s.timestamp_ns = monotonic_ns();
        s.write_problem(problem).unwrap();
        edit(&mut s);
        Job { snapshot: Box::new(s), publisher: 1, received: Instant::now(), received_ns: monotonic_ns() }
    }

    /// The planner's answer of an outcome that was planned.
    fn planned(outcome: (Outcome, StageTimings)) -> (Answer, StageTimings) {
        match outcome {
            (Outcome::Planned(answer, _), timings) => (answer, timings),
            (other, _) => panic!("not planned: {other:?}"),
        }
    }

    #[test]
    fn bad_snapshots_are_rejected_and_change_nothing() {
        let (config, mut admission) = (config(), admission());
        let mut planner = TeamPlanner::preload(&config).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(1).unwrap();
        let first = job(&problem, 5, |_| {});
        let (answer, _) = planned(respond(&config, &mut planner, &mut admission, &first));
        assert_eq!(answer.follow, Follow::New);
        let origin = planner.held().unwrap().origin_ns;
        type Edit = Box<dyn FnOnce(&mut StateSnapshot)>;
        let cases: Vec<(u64, Edit, Reason)> = vec![
            (6, Box::new(|s| s.robot[0].goal[0] = f64::NAN), Reason::NonFinite),
            (7, Box::new(|s| s.robot[2].velocity = [1e6, 0.0, 0.0]), Reason::Implausible),
            (7, Box::new(|s| s.obstacles = 1), Reason::NonPositiveSize),
            (8, Box::new(|s| s.timestamp_ns = 0), Reason::Clock),
            (9, Box::new(|s| s.timestamp_ns += 3_600_000_000_000), Reason::Clock),
            (5, Box::new(|_| {}), Reason::Sequence),
            (4, Box::new(|_| {}), Reason::Sequence),
            (u64::MAX, Box::new(|_| {}), Reason::Sequence),
            (10, Box::new(|s| *s = StateSnapshot { version: 0, ..StateSnapshot::new() }), Reason::Version),
        ];
        for (sequence, edit, reason) in cases {
            let (outcome, _) = respond(&config, &mut planner, &mut admission, &job(&problem, sequence, edit));
            let Outcome::Rejected(rejection, follow) = outcome else { panic!("{outcome:?}") };
            assert_eq!((rejection.reason, follow), (reason, Follow::Held), "sequence {sequence}");
            assert_eq!(planner.held().unwrap().origin_ns, origin, "a rejection keeps the held plan");
            assert_eq!(planner.newest().map(|(s, _)| s), Some(5), "and the newest state");
        }
        // The next valid snapshot is planned: rejected sequences were not recorded.
        let (answer, _) = planned(respond(&config, &mut planner, &mut admission, &job(&problem, 6, |_| {})));
        assert_ne!(answer.follow, Follow::Nothing);
    }

    #[test]
    fn a_snapshot_whose_task_is_rejected_is_still_the_newest_measurement() {
        let (config, mut admission) = (config(), admission());
        let mut planner = TeamPlanner::preload(&config).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(1).unwrap();
        planned(respond(&config, &mut planner, &mut admission, &job(&problem, 5, |_| {})));
        let goals_overlap = job(&problem, 6, |s| s.robot[1].goal = s.robot[0].goal);
        let (outcome, _) = respond(&config, &mut planner, &mut admission, &goals_overlap);
        let Outcome::Task(answer, rejection) = outcome else { panic!("{outcome:?}") };
        assert_eq!((rejection.reason, answer.follow), (Reason::GoalsOverlap, Follow::Held));
        assert_eq!(planner.newest().map(|(s, _)| s), Some(6), "its world is the newest");
    }

    #[test]
    fn one_function_writes_every_field_of_a_reply() {
        let (config, mut admission) = (config(), admission());
        let mut planner = TeamPlanner::preload(&config).unwrap();
        let problem = RandomScenario::new(planner.team().clone()).generate(2).unwrap();
        let j = job(&problem, 7, |_| {});
        let (answer, timings) = planned(respond(&config, &mut planner, &mut admission, &j));
        let held = planner.held().unwrap();
        let mut msg = JointTrajectory::new();
        let timestamp = j.snapshot.timestamp_ns;
        write_reply(&mut msg, &Reply::of(&answer, Some(held), 7, timestamp, j.received_ns, timings));
        assert_eq!((msg.status(), msg.reason(), msg.reason_index), (Ok(PlanStatus::Ok), Ok(Reason::None), u32::MAX));
        assert_eq!((msg.answers_sequence, msg.state_timestamp_ns, msg.received_ns), (7, timestamp, j.received_ns));
        assert_eq!((msg.plan_sequence, msg.plan_origin_ns), (7, timestamp));
        assert_eq!(msg.plan().unwrap(), held.plan);
        assert_eq!((msg.primal_residual, msg.smoothness), (held.primal, held.smoothness));
        assert_eq!((msg.max_speed, msg.max_acceleration), (held.max_speed, held.max_acceleration));
        assert_eq!((msg.iterations, msg.candidates), (answer.iterations as u32, 1));
        // A rejection re-issues the held plan with its own origin and says why.
        let mut msg = JointTrajectory::new();
        write_reply(&mut msg, &Reply::held(Some(held), Reason::GoalsOverlap, 2, 8, timestamp + 20, j.received_ns));
        assert_eq!((msg.status(), msg.reason(), msg.reason_index), (Ok(PlanStatus::Held), Ok(Reason::GoalsOverlap), 2));
        assert_eq!((msg.answers_sequence, msg.plan_sequence, msg.plan_origin_ns), (8, 7, timestamp));
        assert_eq!(msg.plan().unwrap(), held.plan);
        // Without a held plan there is nothing to follow.
        let mut msg = JointTrajectory::new();
        write_reply(&mut msg, &Reply::held(None, Reason::StaleState, u32::MAX, 8, 0, 0));
        assert_eq!((msg.status(), msg.reason()), (Ok(PlanStatus::NoPlan), Ok(Reason::StaleState)));
        assert!(msg.plan().is_err() && msg.primal_residual.is_nan());
    }
}
