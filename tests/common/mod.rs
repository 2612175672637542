//! What the end-to-end tests share: a daemon process on a prefix of its own,
//! and this test process as a controller.

// Each test file uses its own part of these helpers.
#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use flowopt_client::ports::Received;
use flowopt_client::{
    Endpoint, JointTrajectory, PlanStatus, PlanSubscriber, Reason, StatePublisher, StateSnapshot, TeamChannel,
};
use flowopt_planner::problem::{Dim, Problem, Team};
use flowopt_planner::scenario::RandomScenario;

/// How long a test waits for any one answer (the daemon may still be
/// starting).
pub const ANSWER: Duration = Duration::from_secs(30);
/// Robots of the tests' team.
pub const ROBOTS: usize = 4;
/// The tests' team's `stale_after_ms`: wider than a lab's (the shipped
/// configs' 300 ms, a few control periods), since on a loaded 2-core CI
/// machine running a daemon per test, a test's snapshots and the daemon's
/// threads can wait longer than that: at 300 ms a daemon thread not
/// scheduled for that long rightly rejected a snapshot by the clock check,
/// or dropped the held plan as stale before the test's next snapshot, and
/// tests expecting a plan failed.
pub const STALE_AFTER_MS: f64 = 1500.0;

pub fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_flowopt")
}

/// A test's own prefix and configuration file.
pub struct Setup {
    pub prefix: String,
    pub config: PathBuf,
}

impl Setup {
    pub fn new(test: &str) -> Self {
        Self::with_deadline(test, 5000.0)
    }

    /// A setup whose team answers within `deadline_ms`.
    pub fn with_deadline(test: &str, deadline_ms: f64) -> Self {
        let prefix = format!("flowopt-e2e-{}-{test}", std::process::id());
        let config = std::env::temp_dir().join(format!("{prefix}.toml"));
        let text = format!(
            "[[team]]\nname = \"t\"\ndim = 2\nrobots = {ROBOTS}\nrobot = {{ radius = 0.1 }}\n\
             workspace = {{ min = [-1.0, -1.0], max = [1.0, 1.0] }}\nmax_obstacles = 1\n\
             deadline_ms = {deadline_ms:.1}\nstale_after_ms = {STALE_AFTER_MS:.1}\n"
        );
        std::fs::write(&config, text).unwrap();
        Self { prefix, config }
    }

    pub fn daemon(&self) -> Daemon {
        self.daemon_with(&[])
    }

    /// The daemon with `extra` arguments to `flowopt serve`.
    pub fn daemon_with(&self, extra: &[&str]) -> Daemon {
        let child = Command::new(exe())
            .args(["serve", "--config"])
            .arg(&self.config)
            .args(["--ipc-prefix", &self.prefix])
            .args(extra)
            .env("RUST_LOG", "error")
            .stdin(Stdio::null())
            .spawn()
            .unwrap();
        Daemon(child)
    }

    pub fn sim(&self, seconds: f64) -> Command {
        let mut c = Command::new(exe());
        c.args(["sim", "--json", "--seconds", &seconds.to_string(), "--config"])
            .arg(&self.config)
            .args(["--ipc-prefix", &self.prefix])
            .env("RUST_LOG", "error")
            .stdin(Stdio::null());
        c
    }

    /// The channel of the setup's team.
    pub fn channel(&self) -> TeamChannel {
        TeamChannel::new(&self.prefix, "t").unwrap()
    }

    pub fn controller(&self, name: &str) -> Controller {
        let endpoint = Endpoint::new(name).unwrap();
        let channel = TeamChannel::new(&self.prefix, "t").unwrap();
        let states = endpoint.state_publisher(&channel).unwrap();
        let plans = endpoint.plan_subscriber(&channel, &states).unwrap();
        Controller { _endpoint: endpoint, states, plans }
    }
}

impl Drop for Setup {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.config);
    }
}

/// A daemon process, stopped with SIGTERM when dropped.
pub struct Daemon(pub Child);

impl Daemon {
    pub fn signal(&self, signal: i32) {
        // SAFETY: kill(2) on our own child.
        unsafe {
            libc::kill(self.0.id() as libc::pid_t, signal);
        }
    }

    /// SIGTERM, then the exit status (SIGKILL after 10 s).
    pub fn terminate(&mut self) -> Option<ExitStatus> {
        self.signal(libc::SIGTERM);
        let since = Instant::now();
        while since.elapsed() < Duration::from_secs(10) {
            if let Some(status) = self.0.try_wait().unwrap() {
                return Some(status);
            }
            std::thread::sleep(Duration::from_millis(10));
        }
        let _ = self.0.kill();
        let _ = self.0.wait();
        None
    }
}

impl Drop for Daemon {
    fn drop(&mut self) {
        if self.0.try_wait().ok().flatten().is_none() {
            self.terminate();
        }
    }
}

pub struct Controller {
    pub _endpoint: Endpoint,
    pub states: StatePublisher,
    pub plans: PlanSubscriber,
}

pub fn problem(seed: u64) -> Problem {
    RandomScenario::new(Team::default_for(Dim::Two, ROBOTS)).with_obstacles(1).generate(seed).unwrap()
}

impl Controller {
    /// Publishes a snapshot of `p` changed by `edit` and waits for the
    /// plan answering it, re-publishing while the daemon starts (until it
    /// answers anything: a newer snapshot would supersede one whose cold
    /// plan is still running on a loaded machine).
    pub fn request(&mut self, p: &Problem, edit: impl Fn(&mut StateSnapshot)) -> Received<JointTrajectory> {
        let since = Instant::now();
        let mut heard = false;
        loop {
            // The sequence as sent (an edit may change it).
            let mut sequence = 0;
            self.states
                .publish_with(|s| {
                    s.write_problem(p).unwrap();
                    edit(s);
                    sequence = s.sequence;
                })
                .unwrap();
            let round = Instant::now();
            while heard || round.elapsed() < Duration::from_millis(500) {
                if let Some(plan) = self.plans.wait(Duration::from_millis(100)).unwrap() {
                    // Shown when a test fails.
                    eprintln!(
                        "{:?} for {:?} answering {} (waiting for {sequence}) after {:?}",
                        plan.status(),
                        plan.reason(),
                        plan.answers_sequence,
                        since.elapsed()
                    );
                    if plan.answers_sequence == sequence {
                        return plan;
                    }
                    heard = true;
                }
                assert!(since.elapsed() < ANSWER, "no answer to sequence {sequence}");
            }
        }
    }

    /// Waits for the next plan message of `status` and `reason`.
    pub fn wait_for(&mut self, status: PlanStatus, reason: Reason) -> Received<JointTrajectory> {
        wait_for(&mut self.plans, status, reason)
    }
}

/// A process that only watches a team's plans (a team has one state
/// source: a watcher publishes nothing).
pub struct Watcher {
    pub _endpoint: Endpoint,
    pub plans: PlanSubscriber,
}

impl Watcher {
    pub fn new(setup: &Setup, name: &str) -> Self {
        let endpoint = Endpoint::new(name).unwrap();
        let plans = endpoint.plan_watcher(&setup.channel()).unwrap();
        Self { _endpoint: endpoint, plans }
    }
}

/// Waits on `plans` for the next plan message of `status` and `reason`.
pub fn wait_for(plans: &mut PlanSubscriber, status: PlanStatus, reason: Reason) -> Received<JointTrajectory> {
    let since = Instant::now();
    // What came instead, shown when none does.
    let mut seen = std::collections::BTreeMap::<String, usize>::new();
    while since.elapsed() < ANSWER {
        if let Some(plan) = plans.wait(Duration::from_millis(100)).unwrap() {
            if plan.status() == Ok(status) && plan.reason() == Ok(reason) {
                return plan;
            }
            *seen.entry(format!("{:?} for {:?}", plan.status(), plan.reason())).or_default() += 1;
        }
    }
    panic!("no {status:?} message for {reason:?} in {ANSWER:?}; instead: {seen:?}");
}
