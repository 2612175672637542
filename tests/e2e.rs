//! End-to-end tests across real processes: the `flowopt` daemon and
//! simulator as children, this test as a controller, over iceoryx2 shared
//! memory. Every test runs under its own service prefix.

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
/// starting, in a debug build).
const ANSWER: Duration = Duration::from_secs(30);
const ROBOTS: usize = 4;

fn exe() -> &'static str {
    env!("CARGO_BIN_EXE_flowopt")
}

/// A test's own prefix and configuration file.
struct Setup {
    prefix: String,
    config: PathBuf,
}

impl Setup {
    fn new(test: &str) -> Self {
        let prefix = format!("flowopt-e2e-{}-{test}", std::process::id());
        let config = std::env::temp_dir().join(format!("{prefix}.toml"));
        let text = format!(
            "[[team]]\nname = \"t\"\ndim = 2\nrobots = {ROBOTS}\nrobot = {{ radius = 0.1 }}\n\
             workspace = {{ min = [-1.0, -1.0], max = [1.0, 1.0] }}\nmax_obstacles = 1\n\
             deadline_ms = 5000.0\nstale_after_ms = 300.0\n"
        );
        std::fs::write(&config, text).unwrap();
        Self { prefix, config }
    }

    fn daemon(&self) -> Daemon {
        let child = Command::new(exe())
            .args(["serve", "--config"])
            .arg(&self.config)
            .args(["--ipc-prefix", &self.prefix])
            .env("RUST_LOG", "error")
            .stdin(Stdio::null())
            .spawn()
            .unwrap();
        Daemon(child)
    }

    fn sim(&self, seconds: f64) -> Command {
        let mut c = Command::new(exe());
        c.args(["sim", "--json", "--seconds", &seconds.to_string(), "--config"])
            .arg(&self.config)
            .args(["--ipc-prefix", &self.prefix])
            .env("RUST_LOG", "error")
            .stdin(Stdio::null());
        c
    }

    fn controller(&self, name: &str) -> Controller {
        let endpoint = Endpoint::new(name).unwrap();
        let channel = TeamChannel::new(&self.prefix, "t").unwrap();
        let states = endpoint.state_publisher(&channel).unwrap();
        let plans = endpoint.plan_subscriber(&channel).unwrap();
        Controller { _endpoint: endpoint, states, plans }
    }
}

impl Drop for Setup {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.config);
    }
}

/// A daemon process, stopped with SIGTERM when dropped.
struct Daemon(Child);

impl Daemon {
    fn signal(&self, signal: i32) {
        // SAFETY: kill(2) on our own child.
        unsafe {
            libc::kill(self.0.id() as libc::pid_t, signal);
        }
    }

    /// SIGTERM, then the exit status (SIGKILL after 10 s).
    fn terminate(&mut self) -> Option<ExitStatus> {
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

struct Controller {
    _endpoint: Endpoint,
    states: StatePublisher,
    plans: PlanSubscriber,
}

fn problem(seed: u64) -> Problem {
    RandomScenario::new(Team::default_for(Dim::Two, ROBOTS)).with_obstacles(1).generate(seed).unwrap()
}

impl Controller {
    /// Publishes a snapshot of `p` changed by `edit` and waits for the
    /// plan answering it, re-publishing while the daemon starts.
    fn request(&mut self, p: &Problem, edit: impl Fn(&mut StateSnapshot)) -> Received<JointTrajectory> {
        let since = Instant::now();
        loop {
            let sequence = self
                .states
                .publish_with(|s| {
                    s.write_problem(p).unwrap();
                    edit(s);
                })
                .unwrap();
            let round = Instant::now();
            while round.elapsed() < Duration::from_millis(500) {
                if let Some(plan) = self.plans.wait(Duration::from_millis(100)).unwrap()
                    && plan.answers_sequence == sequence
                {
                    return plan;
                }
            }
            assert!(since.elapsed() < ANSWER, "no answer to sequence {sequence}");
        }
    }

    /// Waits for the next plan message of `status`.
    fn wait_for(&self, status: PlanStatus) -> Received<JointTrajectory> {
        let since = Instant::now();
        while since.elapsed() < ANSWER {
            if let Some(plan) = self.plans.wait(Duration::from_millis(100)).unwrap()
                && plan.status == status
            {
                return plan;
            }
        }
        panic!("no {status:?} message");
    }
}

#[test]
fn a_valid_snapshot_gets_a_plan_from_its_state() {
    let setup = Setup::new("valid");
    let mut daemon = setup.daemon();
    let mut c = setup.controller("e2e-valid");
    let p = problem(3);
    let plan = c.request(&p, |_| {});
    assert_eq!(plan.status, PlanStatus::Ok);
    assert_eq!(plan.team_name().unwrap(), "t");
    let start = plan.sample(0.0).unwrap();
    let end = plan.sample(plan.horizon).unwrap();
    for i in 0..ROBOTS {
        assert!((start[i].position - p.starts[i].position).norm() < 1e-9);
        assert!((end[i].position - p.goals[i]).norm() < 1e-9);
        assert!(end[i].velocity.norm() < 1e-9);
    }
    assert!(plan.published_ns >= plan.received_ns && plan.received_ns >= plan.state_timestamp_ns);
    assert_eq!(daemon.terminate().map(|s| s.success()), Some(true), "SIGTERM shuts the daemon down cleanly");
}

#[test]
fn each_malformed_snapshot_is_rejected_and_the_next_valid_one_served() {
    let setup = Setup::new("malformed");
    let _daemon = setup.daemon();
    let mut c = setup.controller("e2e-malformed");
    let p = problem(4);
    type Edit = Box<dyn Fn(&mut StateSnapshot)>;
    let cases: Vec<(&str, Edit, Reason)> = vec![
        ("NaN start", Box::new(|s| s.robot[1].position[0] = f64::NAN), Reason::NonFinite),
        ("n out of range", Box::new(|s| s.robots = 65), Reason::RobotCount),
        ("n not the team's", Box::new(|s| s.robots = 3), Reason::RobotCount),
        ("overlapping starts", Box::new(|s| s.robot[1].position = s.robot[0].position), Reason::StartsOverlap),
        ("overlapping goals", Box::new(|s| s.robot[2].goal = s.robot[3].goal), Reason::GoalsOverlap),
        ("goal out of bounds", Box::new(|s| s.robot[0].goal = [1.5, 0.0, 0.0]), Reason::GoalOutsideWorkspace),
        ("too many obstacles", Box::new(|s| s.obstacles = 2), Reason::ObstacleCount),
        ("wrong dimension", Box::new(|s| s.dim = 3), Reason::Dimension),
        ("wrong version", Box::new(|s| s.version = 0), Reason::Version),
    ];
    for (what, edit, reason) in cases {
        let rejected = c.request(&p, edit);
        assert_eq!((rejected.status, rejected.reason), (PlanStatus::RejectedInput, reason), "{what}");
        drop(rejected);
        let served = c.request(&p, |_| {});
        assert_eq!(served.status, PlanStatus::Ok, "the valid snapshot after {what}");
    }
}

#[test]
fn stale_state_is_reported() {
    let setup = Setup::new("stale");
    let _daemon = setup.daemon();
    let mut c = setup.controller("e2e-stale");
    let p = problem(5);
    let plan = c.request(&p, |_| {});
    assert_eq!(plan.status, PlanStatus::Ok);
    let sequence = plan.answers_sequence;
    drop(plan);
    // No more snapshots: after stale_after_ms the daemon says so, repeating
    // the last plan.
    let stale = c.wait_for(PlanStatus::Stale);
    assert_eq!((stale.reason, stale.answers_sequence), (Reason::StaleState, sequence));
    assert!(stale.sample(0.0).is_ok());
}

#[test]
fn a_killed_and_restarted_client_is_served_again() {
    let setup = Setup::new("client");
    let _daemon = setup.daemon();
    let watcher = setup.controller("e2e-watcher");
    let mut first = setup.sim(600.0).stdout(Stdio::null()).spawn().unwrap();
    // The first simulator is being served ...
    watcher.wait_for(PlanStatus::Ok);
    // ... and dies without cleaning up.
    first.kill().unwrap();
    first.wait().unwrap();
    let second = setup.sim(1.0).output().unwrap();
    assert!(second.status.success(), "{}", String::from_utf8_lossy(&second.stderr));
    let report: serde_json::Value = serde_json::from_slice(&second.stdout).unwrap();
    assert!(report["plans"].as_u64().unwrap() > 0, "{report}");
    assert_eq!(report["rejected"].as_u64(), Some(0));
}

#[test]
fn a_restarted_daemon_is_picked_up_by_its_clients() {
    let setup = Setup::new("restart");
    let mut c = setup.controller("e2e-restart");
    let p = problem(6);
    let mut daemon = setup.daemon();
    assert_eq!(c.request(&p, |_| {}).status, PlanStatus::Ok);
    daemon.signal(libc::SIGKILL);
    daemon.0.wait().unwrap();
    let _again = setup.daemon();
    let plan = c.request(&problem(7), |_| {});
    assert_eq!(plan.status, PlanStatus::Ok);
}
