//! One team's worker thread: takes the newest snapshot, plans, publishes.
//! It owns its own iceoryx2 node and plan publisher (ports are not `Send`)
//! and is the only code that touches the wire: it turns snapshots into
//! problems ([`crate::convert`]), hands them to the team's planner and
//! writes every reply with one function ([`write_reply`]).

use std::time::{Duration, Instant};

use crossbeam::channel::{Receiver, RecvTimeoutError, Sender};
use flowopt_client::clock::monotonic_ns;
use flowopt_client::{
    Endpoint, JointTrajectory, PlanPublisher, PlanStatus, PortError, Reason, StageTimings, StateSnapshot, TeamChannel,
};
use flowopt_planner::plan::JointPlan;
use tracing::{debug, info, info_span, warn};

use crate::config::TeamConfig;
use crate::convert::{Rejection, problem_from};
use crate::planning::{PlanError, Planned, Stages, TeamPlanner, Verdict};

/// A snapshot handed from the WaitSet thread to a worker.
#[derive(Debug)]
pub(crate) struct Job {
    /// The snapshot, copied out of shared memory.
    pub snapshot: Box<StateSnapshot>,
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
    let period = (config.replan_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / config.replan_hz));
    let mut last_sequence = None;
    let mut reported_stale = false;
    loop {
        match jobs.recv_timeout(stale_after) {
            Ok(job) => {
                reported_stale = false;
                let started = Instant::now();
                last_sequence = Some(job.snapshot.sequence);
                answer(&config, &mut planner, &publisher, &job);
                if let Some(period) = period {
                    std::thread::sleep(period.saturating_sub(started.elapsed()));
                }
            }
            Err(RecvTimeoutError::Timeout) => {
                if let (Some(sequence), false) = (last_sequence, reported_stale) {
                    warn!(team = config.name, sequence, "no snapshot for {stale_after:?}: state is stale");
                    let reply = Reply::stale(planner.last_plan(), sequence, monotonic_ns());
                    if let Err(e) = publisher.publish_with(|msg| write_reply(msg, &reply)) {
                        warn!("cannot publish the stale report: {e}");
                    }
                    reported_stale = true;
                }
            }
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    info!(team = config.name, "worker stopped");
}

/// What became of one snapshot.
#[derive(Debug)]
enum Outcome {
    /// A plan was made.
    Planned(Planned),
    /// The snapshot was invalid.
    Rejected(Rejection),
    /// The snapshot was valid but no plan could be made.
    Failed(PlanError),
}

/// Validates the snapshot of `job` and plans it; returns the outcome and
/// the stage times, the validation's included.
fn respond(config: &TeamConfig, planner: &mut TeamPlanner, job: &Job) -> (Outcome, StageTimings) {
    let s = &job.snapshot;
    let t = Instant::now();
    let problem = {
        let _span = info_span!("validate").entered();
        problem_from(s, planner.team(), &config.name, config.max_obstacles)
    };
    let validate = t.elapsed();
    let mut stages = Stages::default();
    let outcome = match problem {
        Err(rejection) => Outcome::Rejected(rejection),
        Ok(problem) => {
            let deadline = job.received + planner.deadline();
            match planner.plan(problem, s.timestamp_ns, deadline, &mut stages) {
                Ok(planned) => Outcome::Planned(planned),
                Err(e) => Outcome::Failed(e),
            }
        }
    };
    let timings = StageTimings {
        queue_us: 0,
        validate_us: us(validate),
        warm_start_us: us(stages.warm_start),
        sample_us: us(stages.sample),
        rank_us: us(stages.rank),
        init_us: us(stages.init),
        filter_us: us(stages.filter),
        optimise_us: us(stages.optimise),
        select_us: us(stages.select),
        total_us: 0,
    };
    (outcome, timings)
}

fn answer(config: &TeamConfig, planner: &mut TeamPlanner, publisher: &PlanPublisher, job: &Job) {
    let s = &job.snapshot;
    let span = info_span!("plan", sequence = s.sequence);
    let _entered = span.enter();
    let queue = job.received.elapsed();
    let (outcome, mut timings) = respond(config, planner, job);
    timings.queue_us = us(queue);
    let _publish = info_span!("publish").entered();
    let result = publisher.publish_with(|msg| {
        timings.total_us = us(job.received.elapsed());
        write_reply(msg, &Reply::answer(&outcome, job, timings));
    });
    match (&outcome, result) {
        (Outcome::Rejected(r), Ok(_)) => warn!(sequence = s.sequence, reason = ?r, "snapshot rejected"),
        (Outcome::Failed(e), Ok(_)) => warn!(sequence = s.sequence, "no plan: {e}"),
        (Outcome::Planned(p), Ok(_)) => {
            debug!(sequence = s.sequence, verdict = ?p.verdict, iterations = p.iterations, "published")
        }
        (_, Err(e)) => warn!(sequence = s.sequence, "cannot publish the plan: {e}"),
    }
}

/// Everything one plan message says.
#[derive(Debug)]
struct Reply<'a> {
    status: PlanStatus,
    reason: Reason,
    reason_index: u32,
    plan: Option<&'a JointPlan>,
    answers_sequence: u64,
    state_timestamp_ns: u64,
    received_ns: u64,
    primal_residual: f64,
    smoothness: f64,
    iterations: usize,
    warm_started: bool,
    candidates: usize,
    timings: StageTimings,
}

impl<'a> Reply<'a> {
    /// The answer to `job`.
    fn answer(outcome: &'a Outcome, job: &Job, timings: StageTimings) -> Self {
        let mut reply = Reply {
            status: PlanStatus::NoPlan,
            reason: Reason::None,
            reason_index: u32::MAX,
            plan: None,
            answers_sequence: job.snapshot.sequence,
            state_timestamp_ns: job.snapshot.timestamp_ns,
            received_ns: job.received_ns,
            primal_residual: f64::NAN,
            smoothness: f64::NAN,
            iterations: 0,
            warm_started: false,
            candidates: 0,
            timings,
        };
        match outcome {
            Outcome::Planned(p) => {
                reply.status = match p.verdict {
                    Verdict::Verified => PlanStatus::Ok,
                    Verdict::IterationCap => PlanStatus::Degraded,
                    Verdict::DeadlineMissed => PlanStatus::DeadlineMissed,
                };
                reply.plan = Some(&p.plan);
                reply.primal_residual = p.primal;
                reply.smoothness = p.smoothness;
                reply.iterations = p.iterations;
                reply.warm_started = p.warm;
                reply.candidates = p.candidates;
            }
            Outcome::Rejected(r) => {
                reply.status = PlanStatus::RejectedInput;
                reply.reason = r.reason;
                reply.reason_index = r.index;
            }
            Outcome::Failed(PlanError::Solver(_)) => reply.reason = Reason::Solver,
        }
        reply
    }

    /// The report that no snapshot arrived after `sequence`: the last plan
    /// repeated, if there is one.
    fn stale(last: Option<(&'a JointPlan, u64)>, sequence: u64, now_ns: u64) -> Self {
        Reply {
            status: if last.is_some() { PlanStatus::Stale } else { PlanStatus::NoPlan },
            reason: Reason::StaleState,
            reason_index: u32::MAX,
            plan: last.map(|(plan, _)| plan),
            answers_sequence: sequence,
            state_timestamp_ns: last.map_or(0, |(_, origin)| origin),
            received_ns: now_ns,
            primal_residual: 0.0,
            smoothness: 0.0,
            iterations: 0,
            warm_started: false,
            candidates: 0,
            timings: StageTimings::default(),
        }
    }
}

/// Writes every field of a reply but those the publisher stamps (`version`,
/// `team`, `published_ns`). A plan the message cannot carry (the
/// configuration was checked against the capacity) becomes `NoPlan`.
fn write_reply(msg: &mut JointTrajectory, reply: &Reply<'_>) {
    msg.status = reply.status;
    msg.reason = reply.reason;
    msg.reason_index = reply.reason_index;
    if let Some(plan) = reply.plan
        && msg.write_plan(plan).is_err()
    {
        msg.status = PlanStatus::NoPlan;
        msg.reason = Reason::Solver;
    }
    msg.answers_sequence = reply.answers_sequence;
    msg.state_timestamp_ns = reply.state_timestamp_ns;
    msg.received_ns = reply.received_ns;
    msg.primal_residual = reply.primal_residual;
    msg.smoothness = reply.smoothness;
    msg.iterations = reply.iterations.min(u32::MAX as usize) as u32;
    msg.warm_started = u32::from(reply.warm_started);
    msg.candidates = reply.candidates.min(u32::MAX as usize) as u32;
    msg.timings = reply.timings;
}

/// Microseconds, saturating at `u32::MAX`.
fn us(d: Duration) -> u32 {
    d.as_micros().min(u32::MAX as u128) as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::problem::{Dim, Team};
    use flowopt_planner::scenario::RandomScenario;

    fn config() -> TeamConfig {
        toml::from_str(
            "name = \"t\"\ndim = 2\nrobots = 4\nrobot = { radius = 0.1 }\n\
             workspace = { min = [-1.0, -1.0], max = [1.0, 1.0] }\nmax_obstacles = 2\ndeadline_ms = 1000.0\n",
        )
        .unwrap()
    }

    fn job(snapshot: StateSnapshot) -> Job {
        Job { snapshot: Box::new(snapshot), received: Instant::now(), received_ns: monotonic_ns() }
    }

    fn snapshot(problem: &flowopt_planner::problem::Problem, sequence: u64) -> StateSnapshot {
        let mut s = StateSnapshot::new();
        s.set_team("t").unwrap();
        s.sequence = sequence;
        s.timestamp_ns = sequence * 10;
        s.write_problem(problem).unwrap();
        s
    }

    #[test]
    fn bad_input_gets_a_rejection_and_keeps_the_last_plan() {
        let config = config();
        let mut planner = TeamPlanner::preload(&config).unwrap();
        let problem = RandomScenario::new(Team::default_for(Dim::Two, 4)).generate(1).unwrap();
        let (first, _) = respond(&config, &mut planner, &job(snapshot(&problem, 1)));
        assert!(matches!(first, Outcome::Planned(_)));
        let mut bad = snapshot(&problem, 2);
        bad.robot[0].goal[0] = f64::NAN;
        let (rejected, _) = respond(&config, &mut planner, &job(bad));
        let Outcome::Rejected(rejection) = rejected else { panic!("{rejected:?}") };
        assert_eq!(rejection.reason, Reason::NonFinite);
        assert_eq!(planner.last_plan().map(|(_, origin)| origin), Some(10), "a rejection keeps the last plan");
    }

    #[test]
    fn one_function_writes_every_field_of_a_planned_reply() {
        let config = config();
        let mut planner = TeamPlanner::preload(&config).unwrap();
        let problem = RandomScenario::new(Team::default_for(Dim::Two, 4)).generate(2).unwrap();
        let j = job(snapshot(&problem, 7));
        let (outcome, timings) = respond(&config, &mut planner, &j);
        let Outcome::Planned(planned) = &outcome else { panic!("{outcome:?}") };
        let mut msg = JointTrajectory::new();
        write_reply(&mut msg, &Reply::answer(&outcome, &j, timings));
        assert_eq!((msg.status, msg.reason, msg.reason_index), (PlanStatus::Ok, Reason::None, u32::MAX));
        assert_eq!((msg.answers_sequence, msg.state_timestamp_ns, msg.received_ns), (7, 70, j.received_ns));
        assert_eq!(msg.plan().unwrap(), planned.plan);
        assert_eq!((msg.primal_residual, msg.smoothness), (planned.primal, planned.smoothness));
        assert_eq!((msg.iterations, msg.warm_started, msg.candidates), (planned.iterations as u32, 0, 1));
        assert!(msg.timings.validate_us > 0 || msg.timings.optimise_us > 0);
        // A rejection carries no plan and says why.
        let rejected = Outcome::Rejected(Rejection { reason: Reason::GoalsOverlap, index: 2 });
        let mut msg = JointTrajectory::new();
        write_reply(&mut msg, &Reply::answer(&rejected, &j, StageTimings::default()));
        assert_eq!((msg.status, msg.reason, msg.reason_index), (PlanStatus::RejectedInput, Reason::GoalsOverlap, 2));
        assert!(msg.plan().is_err() && msg.primal_residual.is_nan());
    }
}
