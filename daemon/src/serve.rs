//! The service: preload every team, then wait on all teams' snapshot
//! events in one WaitSet and hand the newest snapshot of each team to its
//! worker, replacing one the worker has not started yet.

use std::cell::Cell;
use std::net::SocketAddr;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Instant;

use crossbeam::channel::{Receiver, Sender, TrySendError, bounded};
use flowopt_client::clock::monotonic_ns;
use flowopt_client::ports::{DEAD_NODE_SWEEP, cleanup_dead_nodes};
use flowopt_client::{Endpoint, PortError, StateSubscriber, TeamChannel};
use iceoryx2::prelude::*;
use iceoryx2_bb_posix::thread::Thread;
use thiserror::Error;
use tracing::{debug, info, warn};

use crate::config::DaemonConfig;
use crate::lock::{LockError, TeamLock};
use crate::metrics::{Metrics, MetricsError, serve_metrics};
use crate::planning::TeamPlanner;
use crate::preload::PreloadError;
use crate::worker::{self, Job};

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
    /// The metrics endpoint cannot be served.
    #[error(transparent)]
    Metrics(#[from] MetricsError),
}

/// One served team, as seen from the WaitSet thread.
struct Served {
    name: String,
    subscriber: StateSubscriber,
    jobs: Sender<Job>,
    /// A second receiver of `jobs`, to evict a snapshot not yet started.
    evict: Receiver<Job>,
    /// The worker, joined when dropped.
    worker: Thread,
    /// Whether the worker returned (rather than panicked).
    finished: Receiver<bool>,
    /// The team's state source: the publisher whose snapshots are planned.
    source: Cell<Option<u128>>,
    /// Snapshots of a second live publisher ignored so far.
    ignored: Cell<u64>,
}

impl Served {
    /// Hands the newest snapshot, if any, to the worker.
    fn forward(&self) -> Result<(), DaemonError> {
        let Some(sample) = self.subscriber.latest()? else {
            return Ok(());
        };
        let publisher = sample.origin().value();
        if !self.is_the_source(publisher) {
            return Ok(());
        }
        let job = Job {
            snapshot: Box::new(*sample.payload()),
            publisher,
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

    /// Whether a snapshot of `publisher` comes from the team's one state
    /// source. A new publisher becomes the source once the previous one is
    /// gone from the service (a crashed controller's is removed by the
    /// dead-node sweep); while the previous one lives, the newcomer's
    /// snapshots are ignored, unanswered: no controller is to follow a plan
    /// made from another's state. (The state service admits one publisher,
    /// so this only happens on a service another program created with more.)
    fn is_the_source(&self, publisher: u128) -> bool {
        match self.source.get() {
            Some(source) if source == publisher => true,
            Some(source) if self.subscriber.has_publisher(source) => {
                let ignored = self.ignored.get() + 1;
                self.ignored.set(ignored);
                if ignored.is_power_of_two() {
                    warn!(team = self.name, ignored, "a second controller publishes this team's state: ignored");
                }
                false
            }
            previous => {
                if previous.is_some() {
                    info!(team = self.name, "a new controller is the team's state source");
                }
                self.source.set(Some(publisher));
                true
            }
        }
    }
}

/// Runs the daemon until `shutdown` is set (by a signal handler: the
/// signal also interrupts the wait; the WaitSet also wakes every
/// [`DEAD_NODE_SWEEP`] to sweep dead nodes and look at the flag). With
/// `metrics_addr`, serves the teams' Prometheus metrics there
/// ([`crate::metrics`]).
pub fn serve(
    config: &DaemonConfig,
    shutdown: Arc<AtomicBool>,
    metrics_addr: Option<SocketAddr>,
) -> Result<(), DaemonError> {
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
    let metrics = Arc::new(Mutex::new(Metrics::default()));
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
        let team_metrics = metrics.lock().map_err(|_| DaemonError::WorkerGone(team.name.clone()))?.team(&team.name);
        let (finished_tx, finished) = bounded(1);
        let work = move || {
            let run = std::panic::AssertUnwindSafe(|| worker::run(cfg, ch, planner, rx, ready_tx, team_metrics));
            let _ = finished_tx.send(std::panic::catch_unwind(run).is_ok());
        };
        let (worker, _granted) = config
            .realtime
            .spawn_worker(&format!("plan-{}", team.name), work)
            .map_err(|_| DaemonError::WorkerGone(team.name.clone()))?;
        ready.recv().map_err(|_| DaemonError::WorkerGone(team.name.clone()))??;
        let subscriber = endpoint.state_subscriber(&channel)?;
        served.push(Served {
            name: team.name.clone(),
            subscriber,
            jobs,
            evict,
            worker,
            finished,
            source: Cell::new(None),
            ignored: Cell::new(0),
        });
        info!(team = team.name, "serving {}/{}/state", config.ipc.prefix, team.name);
    }

    if let Some(addr) = metrics_addr {
        serve_metrics(addr, Arc::clone(&metrics))?;
    }
    config.realtime.lock_memory_now();
    let waitset = WaitSetBuilder::new()
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<ipc::Service>()
        .map_err(|e| DaemonError::WaitSet(format!("{e:?}")))?;
    let guards = served
        .iter()
        .map(|s| waitset.attach_notification(s.subscriber.listener()))
        .collect::<Result<Vec<_>, _>>()
        .map_err(|e| DaemonError::WaitSet(format!("{e:?}")))?;
    let tick = waitset.attach_interval(DEAD_NODE_SWEEP).map_err(|e| DaemonError::WaitSet(format!("{e:?}")))?;
    // Snapshots published before the daemon started.
    for s in &served {
        s.forward()?;
    }
    info!("ready");

    let mut failure = None;
    while !shutdown.load(Ordering::Relaxed) {
        let result = waitset.wait_and_process(|id| {
            if id.has_event_from(&tick) {
                // A crashed controller's successor can publish once its
                // predecessor's resources are gone.
                if let Err(e) = cleanup_dead_nodes() {
                    debug!("dead-node sweep failed: {e}");
                }
            }
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
        drop(s.worker);
        if s.finished.try_recv() != Ok(true) {
            failure.get_or_insert(DaemonError::WorkerGone(s.name));
        }
    }
    failure.map_or(Ok(()), Err)
}
