//! `flowopt demo`: the daemon and the simulator as two processes on the
//! default configuration, under a service prefix of their own. With
//! `--faults` the simulator injects the controller-side faults of the fault
//! schedule ([`crate::live::faults`]) and the demo the process-side ones: a
//! second daemon for the same team (which must refuse to start) and the
//! daemon killed with SIGKILL and started again. The daemon's resident
//! memory is sampled every second.

use std::io::{BufRead, BufReader};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use serde::Serialize;

use crate::live::daemon_args::DaemonArgs;
use crate::live::faults::{Fault, SCHEDULE};
use crate::live::observe::ObserveArgs;
use crate::live::sim::{SimReport, print_report};

/// How long the daemon may take to exit after SIGTERM.
const SHUTDOWN_GRACE: Duration = Duration::from_secs(5);
/// How long a second daemon may take to refuse.
const REFUSAL_WAIT: Duration = Duration::from_secs(10);
/// Seconds into the run of the first memory sample counted as the start
/// (after preloading and the first plans).
const RSS_SETTLED_S: f64 = 10.0;

/// Run the daemon and the simulator together.
#[derive(Debug, Args)]
pub struct DemoArgs {
    #[command(flatten)]
    daemon: DaemonArgs,
    /// Recording and live view, of the simulated team's traffic (done by
    /// the simulator, which lives through the daemon's restarts).
    #[command(flatten)]
    observe: ObserveArgs,
    /// Seconds of simulation.
    #[arg(long, default_value_t = 30.0)]
    seconds: f64,
    /// Control rate of the simulator (Hz).
    #[arg(long, default_value_t = 50.0)]
    rate_hz: f64,
    /// Seed of the simulated scene.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Inject the fault schedule (controller restart, frozen robots, bad
    /// states, bad clocks, a second daemon, the daemon killed and
    /// restarted) and report every fault's window.
    #[arg(long)]
    faults: bool,
    /// Print one JSON object instead of text.
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    lab: crate::live::sim::LabArgs,
    /// Serve the daemon's Prometheus metrics on this address
    /// (`flowopt serve --metrics`).
    #[arg(long, value_name = "ADDR")]
    metrics: Option<std::net::SocketAddr>,
}

/// What became of the second daemon started for the same team.
#[derive(Debug, Serialize)]
struct SecondDaemon {
    /// It exited by itself with a failure status.
    refused: bool,
    /// Its error named the team's service.
    named_the_service: bool,
}

/// What became of a second controller started for the same team.
#[derive(Debug, Serialize)]
struct SecondController {
    /// It exited by itself with a failure status, before publishing.
    refused: bool,
    /// Its error named the team.
    named_the_team: bool,
}

/// The daemon's resident memory over the run (KiB).
#[derive(Debug, Default, Serialize)]
struct Memory {
    /// At [`RSS_SETTLED_S`] (or the first sample) of the daemon running at the end.
    settled_kib: u64,
    /// At the last sample.
    last_kib: u64,
    /// The largest sample.
    max_kib: u64,
    /// Samples taken.
    samples: u64,
}

/// The demo's summary.
#[derive(Debug, Serialize)]
struct DemoReport {
    #[serde(flatten)]
    sim: SimReport,
    /// Whether the daemon exited cleanly on SIGTERM.
    daemon_clean_exit: bool,
    /// The daemon's resident memory.
    daemon_rss: Memory,
    /// With `--faults`: the second daemon.
    second_daemon: Option<SecondDaemon>,
    /// With `--faults`: daemon restarts after SIGKILL.
    daemon_restarts: u64,
    /// With `--faults`: the second controller.
    second_controller: Option<SecondController>,
}

/// Runs `flowopt demo`; `trace_out` is handed to the first daemon.
pub fn run(args: DemoArgs, trace_out: Option<PathBuf>) -> Result<()> {
    let exe = std::env::current_exe().context("cannot find the flowopt executable")?;
    let prefix = args.daemon.ipc_prefix.clone().unwrap_or_else(|| format!("flowopt-demo-{}", std::process::id()));
    let shared = args.daemon.child_args(&prefix);
    let daemon_command = |trace: Option<&PathBuf>| {
        let mut serve = Command::new(&exe);
        serve.arg("serve").args(&shared);
        if let Some(path) = trace {
            serve.arg("--trace-out").arg(path);
        }
        if let Some(addr) = args.metrics {
            serve.arg("--metrics").arg(addr.to_string());
        }
        serve.stdin(Stdio::null());
        serve
    };
    let mut daemon = daemon_command(trace_out.as_ref()).spawn().context("cannot start the daemon")?;
    let mut sim = Command::new(&exe);
    sim.arg("sim")
        .args(&shared)
        .arg("--json")
        .args(["--seconds", &args.seconds.to_string(), "--rate-hz", &args.rate_hz.to_string()])
        .args(["--seed", &args.seed.to_string()])
        .args(args.observe.child_args())
        .args(args.lab.child_args())
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit());
    if args.faults {
        sim.arg("--faults");
    }
    let mut sim = sim.spawn().context("cannot run the simulator")?;
    let lines = sim.stdout.take().context("the simulator's output")?;
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(lines).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });

    let mut memory = Memory::default();
    let mut second_daemon = None;
    let mut second_controller = None;
    let mut daemon_restarts = 0;
    let mut report_line = None;
    let mut started: Option<Instant> = None;
    let mut done = vec![false; SCHEDULE.len()];
    let mut last_sample = Instant::now();
    let begun = Instant::now();
    loop {
        match rx.recv_timeout(Duration::from_millis(100)) {
            Ok(line) if line.contains("\"ready\"") => started = Some(Instant::now()),
            Ok(line) => report_line = Some(line),
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        if last_sample.elapsed() >= Duration::from_secs(1) {
            last_sample = Instant::now();
            if let Some(kib) = rss_kib(daemon.id()) {
                memory.samples += 1;
                memory.last_kib = kib;
                memory.max_kib = memory.max_kib.max(kib);
                if memory.settled_kib == 0 || begun.elapsed().as_secs_f64() < RSS_SETTLED_S {
                    memory.settled_kib = kib;
                }
            }
        }
        let Some(start) = started.filter(|_| args.faults) else { continue };
        let t = start.elapsed().as_secs_f64();
        for (k, s) in SCHEDULE.iter().enumerate() {
            if done[k] || t < s.at_s || !s.fault.in_demo() {
                continue;
            }
            done[k] = true;
            match s.fault {
                Fault::SecondDaemon => second_daemon = Some(second(&exe, &shared, &prefix)?),
                Fault::SecondController => second_controller = Some(other_controller(&exe, &shared)?),
                Fault::DaemonKill => {
                    daemon.kill().context("cannot kill the daemon")?;
                    daemon.wait()?;
                    daemon = daemon_command(None).spawn().context("cannot restart the daemon")?;
                    daemon_restarts += 1;
                    memory = Memory::default();
                }
                _ => {}
            }
        }
    }
    let status = sim.wait().context("cannot run the simulator")?;
    let daemon_clean_exit = stop_child(&mut daemon)?;
    if !status.success() {
        bail!("the simulator failed ({status})");
    }
    let line = report_line.context("the simulator printed no report")?;
    let sim: SimReport = serde_json::from_str(&line).context("cannot read the simulator's report")?;
    let report =
        DemoReport { sim, daemon_clean_exit, daemon_rss: memory, second_daemon, daemon_restarts, second_controller };
    if args.json {
        println!("{}", serde_json::to_string(&report)?);
    } else {
        print_report(&report.sim);
        println!("daemon           {}", if daemon_clean_exit { "exited cleanly" } else { "did NOT exit cleanly" });
        let m = &report.daemon_rss;
        println!("daemon memory    {} KiB settled, {} KiB last, {} KiB max", m.settled_kib, m.last_kib, m.max_kib);
        if let Some(s) = &report.second_daemon {
            println!("second daemon    refused {}, named the service {}", s.refused, s.named_the_service);
        }
        if let Some(s) = &report.second_controller {
            println!("second controller refused {}, named the team {}", s.refused, s.named_the_team);
        }
    }
    Ok(())
}

/// Starts a second daemon on the same configuration and prefix and waits
/// for it to refuse.
fn second(exe: &PathBuf, shared: &[String], prefix: &str) -> Result<SecondDaemon> {
    let mut child = Command::new(exe)
        .arg("serve")
        .args(shared)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .context("cannot start the second daemon")?;
    let since = Instant::now();
    while since.elapsed() < REFUSAL_WAIT {
        if child.try_wait()?.is_some() {
            let out = child.wait_with_output()?;
            let text = String::from_utf8_lossy(&out.stderr);
            return Ok(SecondDaemon {
                refused: !out.status.success(),
                named_the_service: text.contains(&format!("{prefix}/")),
            });
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    // Still running: it did not refuse. Stop it.
    stop_child(&mut child)?;
    Ok(SecondDaemon { refused: false, named_the_service: false })
}

/// Starts a second simulated controller for the same team and waits for
/// it to be refused (a team has one state source).
fn other_controller(exe: &PathBuf, shared: &[String]) -> Result<SecondController> {
    let mut child = Command::new(exe)
        .arg("sim")
        .args(shared)
        .args(["--seconds", "5", "--seed", "99", "--json"])
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .context("cannot start the second controller")?;
    let since = Instant::now();
    while since.elapsed() < REFUSAL_WAIT {
        if child.try_wait()?.is_some() {
            let out = child.wait_with_output()?;
            let text = String::from_utf8_lossy(&out.stderr);
            return Ok(SecondController { refused: !out.status.success(), named_the_team: text.contains("team \"") });
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    stop_child(&mut child)?;
    Ok(SecondController { refused: false, named_the_team: false })
}

/// The resident set size of process `pid` (KiB), from /proc.
fn rss_kib(pid: u32) -> Option<u64> {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).ok()?;
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

/// Sends SIGTERM and waits; kills after the grace period. Returns whether
/// the process exited by itself with status 0.
pub(crate) fn stop_child(child: &mut Child) -> Result<bool> {
    if let Some(status) = child.try_wait()? {
        return Ok(status.success());
    }
    // SAFETY: plain kill(2) on our own child's pid.
    unsafe {
        libc::kill(child.id() as libc::pid_t, libc::SIGTERM);
    }
    let since = Instant::now();
    while since.elapsed() < SHUTDOWN_GRACE {
        if let Some(status) = child.try_wait()? {
            return Ok(status.success());
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    child.kill()?;
    child.wait()?;
    Ok(false)
}
