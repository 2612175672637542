//! One team's worker thread: takes the newest snapshot, plans, publishes.
//! It owns its own iceoryx2 node and plan publisher (ports are not `Send`).

use std::time::{Duration, Instant};

use crossbeam::channel::{Receiver, RecvTimeoutError, Sender};
use flowopt_client::clock::monotonic_ns;
use flowopt_client::{ClientError, Endpoint, PlanPublisher, PlanStatus, Reason, StateSnapshot, TeamChannel};
use tracing::{debug, info, info_span, warn};

use crate::config::TeamConfig;
use crate::planning::{TeamPlanner, us};

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
    ready: Sender<Result<(), ClientError>>,
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
                answer(&mut planner, &publisher, &job);
                if let Some(period) = period {
                    std::thread::sleep(period.saturating_sub(started.elapsed()));
                }
            }
            Err(RecvTimeoutError::Timeout) => {
                if let (Some(sequence), false) = (last_sequence, reported_stale) {
                    warn!(team = config.name, sequence, "no snapshot for {stale_after:?}: state is stale");
                    report_stale(&planner, &publisher, sequence);
                    reported_stale = true;
                }
            }
            Err(RecvTimeoutError::Disconnected) => break,
        }
    }
    info!(team = config.name, "worker stopped");
}

fn answer(planner: &mut TeamPlanner, publisher: &PlanPublisher, job: &Job) {
    let s = &job.snapshot;
    let span = info_span!("plan", sequence = s.sequence);
    let _entered = span.enter();
    let queue_us = us(job.received.elapsed());
    let mut planned = planner.plan(s, job.received);
    planned.timings.queue_us = queue_us;
    let _publish = info_span!("publish").entered();
    let result = publisher.publish_with(|msg| {
        planned.timings.total_us = us(job.received.elapsed());
        planned.write(msg);
        msg.answers_sequence = s.sequence;
        msg.state_timestamp_ns = s.timestamp_ns;
        msg.received_ns = job.received_ns;
    });
    match result {
        Ok(_) if planned.status == PlanStatus::RejectedInput => {
            warn!(sequence = s.sequence, reason = ?planned.rejection, "snapshot rejected");
        }
        Ok(_) => debug!(sequence = s.sequence, status = ?planned.status, iterations = planned.iterations, "published"),
        Err(e) => warn!(sequence = s.sequence, "cannot publish the plan: {e}"),
    }
}

fn report_stale(planner: &TeamPlanner, publisher: &PlanPublisher, sequence: u64) {
    let result = publisher.publish_with(|msg| {
        msg.reason = Reason::StaleState;
        msg.answers_sequence = sequence;
        msg.received_ns = monotonic_ns();
        match planner.last_plan() {
            Some((plan, origin_ns)) if msg.write_plan(plan).is_ok() => {
                msg.status = PlanStatus::Stale;
                msg.state_timestamp_ns = origin_ns;
            }
            _ => msg.status = PlanStatus::NoPlan,
        }
    });
    if let Err(e) = result {
        warn!("cannot publish the stale report: {e}");
    }
}
