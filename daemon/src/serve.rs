//! The service: preload every team, then wait on all teams' snapshot
//! events in one WaitSet and hand the newest snapshot of each team to its
//! worker, replacing one the worker has not started yet.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam::channel::{Receiver, Sender, TrySendError, bounded};
use flowopt_client::clock::monotonic_ns;
use flowopt_client::ports::cleanup_dead_nodes;
use flowopt_client::{Endpoint, PortError, StateSubscriber, TeamChannel};
use iceoryx2::prelude::*;
use thiserror::Error;
use tracing::{debug, info, warn};

use crate::config::DaemonConfig;
use crate::lock::{LockError, TeamLock};
use crate::planning::{PreloadError, TeamPlanner};
use crate::worker::{self, Job};

/// How often the WaitSet wakes up to look at the shutdown flag, besides
/// the signal that sets it interrupting the wait.
const SHUTDOWN_POLL: Duration = Duration::from_millis(100);

/// Errors that stop the daemon.
#[derive(Debug, Error)]
pub enum DaemonError {
    /// Another daemon serves a configured team.
    #[error(transparent)]
    Served(#[from] LockError),
    /// A team's planner could not be built.
    #[error("team {team:?}: {source}")]
    Preload {
        /// Team name.
        team: String,
        /// Cause.
        source: PreloadError,
    },
    /// An iceoryx2 port could not be opened or used.
    #[error(transparent)]
    Ipc(#[from] PortError),
    /// The WaitSet failed.
    #[error("WaitSet: {0}")]
    WaitSet(String),
    /// A worker thread ended unexpectedly.
    #[error("the worker of team {0:?} stopped")]
    WorkerGone(String),
}

/// One served team, as seen from the WaitSet thread.
struct Served {
    name: String,
    subscriber: StateSubscriber,
    jobs: Sender<Job>,
    /// A second receiver of `jobs`, to evict a snapshot not yet started.
    evict: Receiver<Job>,
    worker: JoinHandle<()>,
}

impl Served {
    /// Hands the newest snapshot, if any, to the worker.
    fn forward(&self) -> Result<(), DaemonError> {
        let Some(sample) = self.subscriber.latest()? else {
            return Ok(());
        };
        let job = Job {
            snapshot: Box::new(*sample.payload()),
            publisher: sample.origin().value(),
            received: Instant::now(),
            received_ns: monotonic_ns(),
        };
        drop(sample);
        match self.jobs.try_send(job) {
            Ok(()) => Ok(()),
            Err(TrySendError::Full(job)) => {
                if let Ok(old) = self.evict.try_recv() {
                    debug!(team = self.name, sequence = old.snapshot.sequence, "superseded before planning");
                }
                self.jobs.try_send(job).map_err(|_| DaemonError::WorkerGone(self.name.clone()))
            }
            Err(TrySendError::Disconnected(_)) => Err(DaemonError::WorkerGone(self.name.clone())),
        }
    }
}

/// Runs the daemon until `shutdown` is set (by a signal handler: the
/// signal also interrupts the wait).
pub fn serve(config: &DaemonConfig, shutdown: Arc<AtomicBool>) -> Result<(), DaemonError> {
    match cleanup_dead_nodes() {
        Ok(0) => {}
        Ok(n) => info!("removed the resources of {n} dead iceoryx2 nodes"),
        Err(e) => warn!("dead-node cleanup failed: {e}"),
    }
    // Refuse before any preloading if another daemon serves a team.
    let _locks = config
        .teams
        .iter()
        .map(|team| TeamLock::acquire(&config.ipc.prefix, &team.name))
        .collect::<Result<Vec<_>, _>>()?;
    let endpoint = Endpoint::new("flowopt-daemon")?;
    let mut served = Vec::new();
    for team in &config.teams {
        let started = Instant::now();
        let planner =
            TeamPlanner::preload(team).map_err(|source| DaemonError::Preload { team: team.name.clone(), source })?;
        info!(team = team.name, robots = team.robots, "preloaded in {:?}", started.elapsed());
        let channel = TeamChannel::new(&config.ipc.prefix, &team.name)?;
        let (jobs, rx) = bounded(1);
        let (ready_tx, ready) = bounded(1);
        let evict = rx.clone();
        let (cfg, ch) = (team.clone(), channel.clone());
        let worker = std::thread::Builder::new()
            .name(format!("plan-{}", team.name))
            .spawn(move || worker::run(cfg, ch, planner, rx, ready_tx))
            .map_err(|_| DaemonError::WorkerGone(team.name.clone()))?;
        ready.recv().map_err(|_| DaemonError::WorkerGone(team.name.clone()))??;
        let subscriber = endpoint.state_subscriber(&channel)?;
        served.push(Served { name: team.name.clone(), subscriber, jobs, evict, worker });
        info!(team = team.name, "serving {}/{}/state", config.ipc.prefix, team.name);
    }

    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| DaemonError::WaitSet(format!("{e:?}")))?;
    let guards = served
        .iter()
        .map(|s| waitset.attach_notification(s.subscriber.listener()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| DaemonError::WaitSet(format!("{e:?}")))?;
    let _tick = waitset.attach_interval(SHUTDOWN_POLL).map_err(|e| DaemonError::WaitSet(format!("{e:?}")))?;
    // Snapshots published before the daemon started.
    for s in &served {
        s.forward()?;
    }
    info!("ready");

    let mut failure = None;
    while !shutdown.load(Ordering::Relaxed) {
        let result = waitset.wait_and_process(|id| {
            for (s, guard) in served.iter().zip(&guards) {
                if id.has_event_from(guard)
                    && let Err(e) = s.forward()
                {
                    failure = Some(e);
                    return CallbackProgression::Stop;
                }
            }
            if shutdown.load(Ordering::Relaxed) { CallbackProgression::Stop } else { CallbackProgression::Continue }
        });
        if let Err(e) = result {
            failure = Some(DaemonError::WaitSet(format!("{e:?}")));
        }
        if failure.is_some() {
            break;
        }
    }
    drop(guards);
    info!("shutting down");
    for s in served {
        drop(s.jobs);
        drop(s.evict);
        if s.worker.join().is_err() {
            failure.get_or_insert(DaemonError::WorkerGone(s.name));
        }
    }
    failure.map_or(Ok(()), Err)
}
