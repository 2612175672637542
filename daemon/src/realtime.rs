//! The `[realtime]` section: how the daemon asks the operating system for
//! predictable timing, and what it reports when that is refused.
//!
//! - **Worker priority.** Each team's worker (the thread that must publish
//!   every answer by its deadline) runs under `SCHED_FIFO` at
//!   `worker_priority` (1-99, the range `chrt` uses), so that it runs as
//!   soon as it wakes instead of waiting for a scheduler slice behind the
//!   cold-planning threads: measured on a 2-core host, a 16-robot demo had
//!   2-5 answers in 60 s published 2-3 ms past the 20 ms deadline under the
//!   normal scheduler and none under `SCHED_FIFO` (docs/BENCHMARKS.md).
//!   Refused without `CAP_SYS_NICE` or an rtprio limit (`ulimit -r`): the
//!   worker then runs under the normal scheduler, and a warning says so.
//!   Between snapshots the worker sleeps (a wake each `stale_after_ms` while
//!   no controller publishes): a real-time thread that spun would take a
//!   core from every other process (`tests/e2e.rs`,
//!   `an_idle_daemon_leaves_the_cores_alone`).
//! - **Memory locking** (`lock_memory`): every page mapped now and later is
//!   locked (`mlockall`), after the engines are preloaded, so that no
//!   answer waits for a page fault. Refused without `CAP_IPC_LOCK` or a
//!   large enough `ulimit -l`: reported, and the daemon runs on.
//! - **CPU pinning** (`worker_cpus`): the workers run on these CPUs only.

use std::sync::{Arc, Mutex};

use iceoryx2_bb_posix::memory_lock::{LockMode, MemoryLock};
use iceoryx2_bb_posix::scheduler::Scheduler;
use iceoryx2_bb_posix::thread::{Thread, ThreadBuilder, ThreadName, ThreadSpawnError};
use serde::Deserialize;
use tracing::{info, warn};

/// The `[realtime]` section of the daemon's configuration.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RealtimeConfig {
    /// `SCHED_FIFO` priority of each team's worker thread (1-99); 0 runs it
    /// under the normal scheduler.
    #[serde(default = "default_worker_priority")]
    pub worker_priority: u8,
    /// Lock the daemon's memory (`mlockall`) once the teams are preloaded.
    #[serde(default)]
    pub lock_memory: bool,
    /// CPUs the workers are pinned to (empty: any).
    #[serde(default)]
    pub worker_cpus: Vec<usize>,
}

fn default_worker_priority() -> u8 {
    10
}

impl Default for RealtimeConfig {
    fn default() -> Self {
        Self { worker_priority: default_worker_priority(), lock_memory: false, worker_cpus: Vec::new() }
    }
}

/// What the operating system granted.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Granted {
    /// The worker runs under `SCHED_FIFO`.
    pub fifo: bool,
    /// The worker is pinned as asked.
    pub pinned: bool,
}

impl RealtimeConfig {
    /// Checks the values.
    pub fn check(&self) -> Result<(), String> {
        if self.worker_priority > 99 {
            return Err(format!("realtime.worker_priority {} is not in 0-99", self.worker_priority));
        }
        Ok(())
    }

    /// Locks the process's memory if asked; reports a refusal.
    pub fn lock_memory_now(&self) {
        if !self.lock_memory {
            return;
        }
        let locked = MemoryLock::lock_all(LockMode::LockAllPagesCurrentlyMapped)
            .and_then(|()| MemoryLock::lock_all(LockMode::LockAllPagesThatBecomeMapped));
        match locked {
            Ok(()) => info!("memory locked (mlockall)"),
            Err(e) => warn!(
                "realtime.lock_memory refused ({e:?}): pages may fault on the planning path; \
                 grant CAP_IPC_LOCK or raise `ulimit -l`"
            ),
        }
    }

    /// Spawns a worker named `name` running `work`, at the configured
    /// priority and on the configured CPUs where the system allows; what it
    /// refuses is reported and the worker runs without it.
    pub fn spawn_worker<F>(&self, name: &str, work: F) -> Result<(Thread, Granted), ThreadSpawnError>
    where
        F: FnOnce() + Send + 'static,
    {
        let thread_name = ThreadName::from_bytes_truncated(name.as_bytes()).ok();
        let base = || match &thread_name {
            Some(n) => ThreadBuilder::new().name(n),
            None => ThreadBuilder::new(),
        };
        let mut granted = Granted::default();
        // A refused spawn drops its closure: the work waits here until a
        // spawn succeeds, and that thread takes it.
        let work = Arc::new(Mutex::new(Some(work)));
        let run = || {
            let work = Arc::clone(&work);
            move || {
                let taken = work.lock().ok().and_then(|mut w| w.take());
                if let Some(work) = taken {
                    work();
                }
            }
        };
        let pinned = |b: ThreadBuilder| if self.worker_cpus.is_empty() { b } else { b.affinity(&self.worker_cpus) };
        if self.worker_priority > 0 {
            let fifo = pinned(base())
                .inherit_scheduling_attributes(false)
                .scheduler(Scheduler::Fifo)
                .priority(fifo_scale(self.worker_priority));
            match fifo.spawn(run()) {
                Ok(thread) => {
                    granted = Granted { fifo: true, pinned: !self.worker_cpus.is_empty() };
                    info!(worker = name, priority = self.worker_priority, "worker under SCHED_FIFO");
                    return Ok((thread, granted));
                }
                Err(e) => warn!(
                    worker = name,
                    "realtime.worker_priority {} refused ({e:?}): the worker runs under the normal scheduler, \
                     and answers may be published late on a busy machine; grant CAP_SYS_NICE or an rtprio limit",
                    self.worker_priority
                ),
            }
        }
        if !self.worker_cpus.is_empty() {
            match pinned(base()).spawn(run()) {
                Ok(thread) => {
                    granted.pinned = true;
                    return Ok((thread, granted));
                }
                Err(e) => warn!(worker = name, "realtime.worker_cpus {:?} refused ({e:?})", self.worker_cpus),
            }
        }
        base().spawn(run()).map(|thread| (thread, granted))
    }
}

/// A `SCHED_FIFO` priority (1-99) on iceoryx2's scale (0-255 over the
/// scheduler's range), rounded so that it maps back to the same priority.
fn fifo_scale(priority: u8) -> u8 {
    let p = f64::from(priority.clamp(1, 99) - 1);
    (p * 255.0 / 98.0).ceil().min(255.0) as u8
}

/// How much nicer (Linux `nice`) than the rest of the process the cold
/// lanes run: on a machine where the controller shares the cores, a cold
/// plan running past its snapshot's deadline yields to the controller's
/// and the simulator's threads instead of taking a core from them for a
/// time slice (the worker, under SCHED_FIFO, preempts them anyway).
const LANE_NICENESS: i32 = 5;

/// Lowers the calling thread's priority by [`LANE_NICENESS`] (best effort;
/// a refusal is logged): what each cold-planning lane runs first.
pub fn lower_lane_priority() {
    // SAFETY: plain syscalls on the calling thread.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        let now = libc::getpriority(libc::PRIO_PROCESS, tid);
        if libc::setpriority(libc::PRIO_PROCESS, tid, now + LANE_NICENESS) != 0 {
            warn!("cannot lower a cold-planning thread's priority");
        }
    }
}

/// Moves the calling thread to `SCHED_IDLE` (it runs only on a core
/// nothing else wants; best effort, a refusal is logged): what the braking
/// bound's background thread runs first, so that its linear programs
/// (about a second of one core when a team first moves) never take a core
/// from the controllers, the simulator or the cold lanes (a speed not
/// solved yet only means a smaller bound a little longer).
pub fn idle_priority() {
    let param = libc::sched_param { sched_priority: 0 };
    // SAFETY: a plain syscall on the calling thread (pid 0), with a valid
    // parameter.
    if unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) } != 0 {
        warn!("cannot move a background thread to SCHED_IDLE");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fifo_priorities_map_to_iceoryx2s_scale_and_back() {
        for p in 1..=99u8 {
            let v = fifo_scale(p);
            // iceoryx2: min + (max - min) * v / 255, truncated.
            let back = 1 + (98.0 * f64::from(v) / 255.0) as u8;
            assert_eq!(back, p, "{p} -> {v}");
        }
    }

    #[test]
    fn a_worker_runs_whatever_the_system_grants() {
        let (tx, rx) = std::sync::mpsc::channel();
        let config = RealtimeConfig { worker_priority: 10, lock_memory: false, worker_cpus: vec![0] };
        let (thread, _granted) = config.spawn_worker("rt-test", move || tx.send(42).unwrap()).unwrap();
        assert_eq!(rx.recv().unwrap(), 42);
        drop(thread);
        assert!(RealtimeConfig { worker_priority: 120, ..config }.check().is_err());
    }
}
