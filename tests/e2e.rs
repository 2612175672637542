//! End-to-end tests across real processes: the `flowopt` daemon and
//! simulator as children, this test as a controller, over iceoryx2 shared
//! memory. Every test runs under its own service prefix.

mod common;

use std::process::Stdio;

use common::{ROBOTS, Setup, Watcher, problem, wait_for};
use flowopt_client::{PlanStatus, Reason, StateSnapshot};

#[test]
fn a_valid_snapshot_gets_a_plan_from_its_state() {
    let setup = Setup::new("valid");
    let mut daemon = setup.daemon();
    let mut c = setup.controller("e2e-valid");
    let p = problem(3);
    let plan = c.request(&p, |_| {});
    assert_eq!(plan.status(), Ok(PlanStatus::Ok));
    assert_eq!((plan.plan_sequence, plan.plan_origin_ns), (plan.answers_sequence, plan.state_timestamp_ns));
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
    use PlanStatus::{Held, NoPlan};
    let cases: Vec<(&str, Edit, PlanStatus, Reason)> = vec![
        ("NaN start", Box::new(|s| s.robot[1].position[0] = f64::NAN), Held, Reason::NonFinite),
        ("n out of range", Box::new(|s| s.robots = flowopt_client::MAX_ROBOTS as u32 + 1), Held, Reason::RobotCount),
        ("n not the team's", Box::new(|s| s.robots = 3), Held, Reason::RobotCount),
        // Measured in contact: the robots are not on the held plan, and no
        // stopping plan starts from overlapping robots.
        ("overlapping starts", Box::new(|s| s.robot[1].position = s.robot[0].position), NoPlan, Reason::StartsOverlap),
        ("overlapping goals", Box::new(|s| s.robot[2].goal = s.robot[3].goal), Held, Reason::GoalsOverlap),
        ("goal out of bounds", Box::new(|s| s.robot[0].goal = [1.5, 0.0, 0.0]), Held, Reason::GoalOutsideWorkspace),
        ("too many obstacles", Box::new(|s| s.obstacles = 2), Held, Reason::ObstacleCount),
        ("wrong dimension", Box::new(|s| s.dim = 3), Held, Reason::Dimension),
        ("wrong version", Box::new(|s| s.version = 0), Held, Reason::Version),
        ("junk after the team's name", Box::new(|s| s.team[2..6].copy_from_slice(b"junk")), Held, Reason::Team),
    ];
    let first = c.request(&p, |_| {});
    assert_eq!(first.status(), Ok(PlanStatus::Ok));
    drop(first);
    for (what, edit, status, reason) in cases {
        let rejected = c.request(&p, edit);
        // The held plan is re-issued (where the robots are still on it),
        // and the message says why.
        assert_eq!((rejected.status(), rejected.reason()), (Ok(status), Ok(reason)), "{what}");
        drop(rejected);
        let served = c.request(&p, |_| {});
        assert_eq!(served.status(), Ok(PlanStatus::Ok), "the valid snapshot after {what}");
    }
}

#[test]
fn stale_state_is_reported() {
    let setup = Setup::new("stale");
    let _daemon = setup.daemon();
    let mut c = setup.controller("e2e-stale");
    let p = problem(5);
    let plan = c.request(&p, |_| {});
    assert_eq!(plan.status(), Ok(PlanStatus::Ok));
    let (sequence, origin) = (plan.answers_sequence, plan.plan_origin_ns);
    drop(plan);
    // No more snapshots: after stale_after_ms the daemon says so, and
    // re-issues nothing: without a measurement it cannot check a plan.
    let stale = c.wait_for(PlanStatus::NoPlan, Reason::StaleState);
    assert_eq!(stale.answers_sequence, sequence);
    assert_ne!(stale.plan_origin_ns, origin);
}

#[test]
fn a_lab_day_changes_goals_kicks_robots_and_sends_walkers_through_the_snapshots() {
    let setup = Setup::new("lab");
    let _daemon = setup.daemon();
    let day = ["--goal-changes", "120", "--gusts", "120", "--walkers", "2"];
    let out = setup.sim(3.0).args(day).output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let lab = &report["lab"];
    assert_eq!(lab["day"]["walkers"].as_u64(), Some(2), "{report}");
    assert_eq!(lab["walkers"].as_u64(), Some(2), "two walkers entered and are still crossing: {report}");
    // 4 robots, 3 s at 120 per robot-minute: 24 of each expected.
    assert!(lab["gusts"].as_u64().unwrap() >= 5, "{report}");
    assert!(report["closest_obstacle_approach"].is_number(), "the walkers were there: {report}");
    assert!(report["plans"].as_u64().unwrap() > 0, "{report}");
    let bad = setup.sim(1.0).arg("--gusts=-1").output().unwrap();
    assert!(!bad.status.success());
    let line = String::from_utf8_lossy(&bad.stderr);
    assert!(line.contains("must be finite and not negative"), "{line}");
}

#[test]
fn a_killed_and_restarted_client_is_served_again() {
    let setup = Setup::new("client");
    let _daemon = setup.daemon();
    let mut watcher = Watcher::new(&setup, "e2e-watcher");
    let mut first = setup.sim(600.0).stdout(Stdio::null()).spawn().unwrap();
    // The first simulator is being served ...
    wait_for(&mut watcher.plans, PlanStatus::Ok, Reason::None);
    // ... and dies without cleaning up.
    first.kill().unwrap();
    first.wait().unwrap();
    let second = setup.sim(1.0).output().unwrap();
    assert!(second.status.success(), "{}", String::from_utf8_lossy(&second.stderr));
    let report: serde_json::Value = serde_json::from_slice(&second.stdout).unwrap();
    assert!(report["plans"].as_u64().unwrap() > 0, "{report}");
    assert_eq!(report["contacts"].as_u64(), Some(0), "{report}");
    let rejections: u64 = report["reasons"]
        .as_object()
        .unwrap()
        .iter()
        .filter(|(r, _)| !matches!(r.as_str(), "DeadlineMissed" | "NotVerified" | "NotFollowing"))
        .map(|(_, n)| n.as_u64().unwrap())
        .sum();
    assert_eq!(rejections, 0, "{report}");
}

#[test]
fn an_idle_daemon_leaves_the_cores_alone() {
    // Its worker runs under SCHED_FIFO where allowed: a worker that spins
    // while no controller publishes takes a core from every other process
    // (two such daemons starved this file's simulators on a 2-core machine).
    let setup = Setup::new("idle");
    let daemon = setup.daemon();
    let worker = || worker_cpu_seconds(daemon.0.id());
    let since = std::time::Instant::now();
    while worker().is_none() {
        assert!(since.elapsed() < common::ANSWER, "the daemon started no worker");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let before = worker().unwrap();
    // Past the team's stale_after (1.5 s), twice over.
    std::thread::sleep(std::time::Duration::from_secs(4));
    let used = worker().unwrap() - before;
    assert!(used < 0.5, "the idle worker used {used:.2} s of CPU in 4 s");
}

/// CPU seconds (user and system) of the daemon `pid`'s team worker
/// (`plan-t`), once it runs.
fn worker_cpu_seconds(pid: u32) -> Option<f64> {
    // SAFETY: sysconf has no preconditions.
    let ticks = unsafe { libc::sysconf(libc::_SC_CLK_TCK) } as f64;
    for task in std::fs::read_dir(format!("/proc/{pid}/task")).ok()?.flatten() {
        let stat = std::fs::read_to_string(task.path().join("stat")).unwrap_or_default();
        // pid (comm) state ...: utime and stime are fields 14 and 15.
        let Some((head, tail)) = stat.rsplit_once(')') else { continue };
        if !head.ends_with("(plan-t") {
            continue;
        }
        let fields: Vec<&str> = tail.split_whitespace().collect();
        let cpu: f64 = fields[11..13].iter().map(|f| f.parse::<f64>().unwrap()).sum();
        return Some(cpu / ticks);
    }
    None
}

#[test]
fn a_restarted_daemon_is_picked_up_by_its_clients() {
    let setup = Setup::new("restart");
    let mut c = setup.controller("e2e-restart");
    let p = problem(6);
    let mut daemon = setup.daemon();
    assert_eq!(c.request(&p, |_| {}).status(), Ok(PlanStatus::Ok));
    daemon.signal(libc::SIGKILL);
    daemon.0.wait().unwrap();
    // The dead daemon's lock does not block its successor.
    let _again = setup.daemon();
    let plan = c.request(&problem(7), |_| {});
    assert_eq!(plan.status(), Ok(PlanStatus::Ok));
}

/// `GET path` from `addr`, retried while the daemon starts.
fn scrape(addr: &str, path: &str) -> String {
    use std::io::{Read, Write};
    let since = std::time::Instant::now();
    loop {
        if let Ok(mut stream) = std::net::TcpStream::connect(addr) {
            stream.write_all(format!("GET {path} HTTP/1.1\r\nHost: flowopt\r\n\r\n").as_bytes()).unwrap();
            let mut text = String::new();
            stream.read_to_string(&mut text).unwrap();
            return text;
        }
        assert!(since.elapsed() < common::ANSWER, "nothing listens on {addr}");
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

#[test]
fn the_metrics_endpoint_counts_the_answers_by_status_and_reason() {
    // A port the system had free a moment ago.
    let port = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap().port();
    let addr = format!("127.0.0.1:{port}");
    let setup = Setup::new("metrics");
    let _daemon = setup.daemon_with(&["--metrics", &addr]);
    let mut c = setup.controller("e2e-metrics");
    let p = problem(3);
    for _ in 0..3 {
        assert!(c.request(&p, |_| {}).status().unwrap().followable());
    }
    assert_eq!(c.request(&p, |s| s.robot[0].position[0] = f64::NAN).reason(), Ok(Reason::NonFinite));
    let text = scrape(&addr, "/metrics");
    assert!(text.starts_with("HTTP/1.1 200 OK"), "{text}");
    let count = |prefix: &str| -> f64 {
        text.lines().filter(|l| l.starts_with(prefix)).filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok()).sum()
    };
    let followable = ["Ok", "Held", "Stopping"]
        .iter()
        .map(|s| count(&format!("flowopt_answers_total{{team=\"t\",status=\"{s}\"")))
        .sum::<f64>();
    assert!(followable >= 3.0, "{text}");
    assert!(count("flowopt_answers_total{team=\"t\",status=\"Held\",reason=\"NonFinite\"}") >= 1.0, "{text}");
    assert!(count("flowopt_answer_latency_seconds_count{team=\"t\"}") >= 4.0, "{text}");
}

#[test]
fn an_installed_binary_runs_the_demo_from_an_empty_directory_with_the_learned_racer() {
    // The binary alone, as `cargo install` leaves it, run where there is
    // no configuration and no weights.
    let root = std::env::temp_dir().join(format!("flowopt-e2e-{}-installed", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    std::fs::create_dir_all(root.join("bin")).unwrap();
    std::fs::create_dir_all(root.join("empty")).unwrap();
    let installed = root.join("bin/flowopt");
    std::fs::copy(common::exe(), &installed).unwrap();
    let out = std::process::Command::new(&installed)
        .args(["demo", "--seconds", "3", "--json"])
        .current_dir(root.join("empty"))
        .env_remove("FLOWOPT_CONFIG")
        .env("RUST_LOG", "info")
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let log = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{log}");
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(report["statuses"]["Ok"].as_u64().unwrap_or(0) > 0, "{report}");
    assert!(log.contains("cold planners: learned, optimiser"), "the learned racer is loaded:\n{log}");
    std::fs::remove_dir_all(&root).unwrap();
}
