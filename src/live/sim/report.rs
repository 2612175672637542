//! What a simulation run reports: the run's tally, each fault's window and
//! the lab's day, as JSON or for people.

use serde::{Deserialize, Serialize};

use super::lab::LabReport;
use super::tally::Tally;

/// One fault's window of a run.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FaultReport {
    /// The fault.
    pub fault: String,
    /// When it was injected (s into the run).
    pub at_s: f64,
    /// Where its window ends (s).
    pub until_s: f64,
    /// What the window saw.
    #[serde(flatten)]
    pub tally: Tally,
}

/// What a simulation run saw.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct SimReport {
    /// Seconds simulated (after the first answer).
    pub seconds: f64,
    /// Control rate (Hz).
    pub rate_hz: f64,
    /// Robots.
    pub robots: usize,
    /// Snapshots published.
    pub snapshots: u64,
    /// Messages answering the newest snapshot published when they arrived.
    pub plans_answering_newest: u64,
    /// Snapshot timestamp to the receipt of its answer, median (ms).
    pub latency_p50_ms: f64,
    /// 99th percentile (ms).
    pub latency_p99_ms: f64,
    /// 99.9th percentile (ms).
    pub latency_p999_ms: f64,
    /// Maximum (ms).
    pub latency_max_ms: f64,
    /// Longest the simulator's own check of a followed plan held up its
    /// control loop (ms).
    pub check_max_ms: f64,
    /// New plans that were warm-started.
    pub warm: u64,
    /// The whole run.
    #[serde(flatten)]
    pub overall: Tally,
    /// Mean distance from the followed position (m).
    pub mean_tracking_error_m: f64,
    /// Largest distance from the followed position (m).
    pub max_tracking_error_m: f64,
    /// Goal sets reached by the whole team.
    pub goal_sets_reached: u64,
    /// Per injected fault (with `--faults`).
    pub faults: Vec<FaultReport>,
    /// The lab's day (with `--lab` or its options).
    pub lab: Option<LabReport>,
    /// The run's first contacts of either kind, as each began (at most
    /// [`CONTACTS_LOGGED`]; the tallies count all of them).
    #[serde(default)]
    pub contact_log: Vec<ContactEvent>,
}

/// How many contacts a run's report describes one by one.
pub const CONTACTS_LOGGED: usize = 100;

/// One contact as it began, with what the team was doing then.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ContactEvent {
    /// When it began (s into the run).
    pub at_s: f64,
    /// The robot (of a pair of robots, the lower index).
    pub robot: usize,
    /// The other robot's index, for a robot-robot contact.
    pub other_robot: Option<usize>,
    /// The obstacle's index in the world's list then, for a robot-obstacle
    /// contact.
    pub obstacle: Option<usize>,
    /// The robot's speed (m/s).
    pub speed_mps: f64,
    /// The other robot's or the obstacle's speed (m/s).
    pub other_speed_mps: f64,
    /// Where the robot was (m).
    pub position_m: [f64; 3],
    /// Where the other robot or the obstacle was (m).
    pub other_position_m: [f64; 3],
    /// The status of the plan the team followed (`None`: it had none and
    /// braked).
    pub following: Option<String>,
    /// How far into that plan the team was (ms from its time origin).
    pub plan_age_ms: Option<f64>,
    /// The newest answer's status and reason before the contact.
    pub last_answer: Option<String>,
    /// Time since the newest `Ok` answer (ms; `None` before any).
    pub since_ok_ms: Option<f64>,
    /// The answers of the half second before it, oldest first: how long
    /// before the contact each came (ms), its status and reason.
    pub answers_before: Vec<(f64, String)>,
}

/// Prints a report for people.
pub fn print_report(r: &SimReport) {
    print_summary(r);
    for c in &r.contact_log {
        let with = match (c.other_robot, c.obstacle) {
            (Some(j), _) => format!("robot {j} at {:.2} m/s", c.other_speed_mps),
            (None, Some(m)) => format!("obstacle {m} at {:.2} m/s", c.other_speed_mps),
            (None, None) => "?".into(),
        };
        println!(
            "contact at {:>6.2} s: robot {} at {:.2} m/s with {with}; following {} ({} ms in), last answer {}, {} ms since Ok",
            c.at_s,
            c.robot,
            c.speed_mps,
            c.following.as_deref().unwrap_or("nothing"),
            c.plan_age_ms.map_or("-".into(), |a| format!("{a:.0}")),
            c.last_answer.as_deref().unwrap_or("none"),
            c.since_ok_ms.map_or("-".into(), |a| format!("{a:.0}")),
        );
    }
}

fn print_summary(r: &SimReport) {
    let t = &r.overall;
    println!(
        "{} robots, {:.0} s at {:.0} Hz: {} snapshots, {} messages",
        r.robots, r.seconds, r.rate_hz, r.snapshots, t.plans
    );
    println!("statuses         {:?} (warm-started {})", t.statuses, r.warm);
    println!("reasons          {:?}", t.reasons);
    println!("answering newest {} of {}", r.plans_answering_newest, t.plans);
    println!(
        "state-to-answer  p50 {:.2} ms, p99 {:.2} ms, p99.9 {:.2} ms, max {:.2} ms",
        r.latency_p50_ms, r.latency_p99_ms, r.latency_p999_ms, r.latency_max_ms
    );
    println!(
        "contacts         {} robot-robot (closest {:.3} of the separation), {} robot-obstacle (closest {:.3})",
        t.contacts,
        t.closest_approach.unwrap_or(f64::NAN),
        t.obstacle_contacts,
        t.closest_obstacle_approach.unwrap_or(f64::NAN)
    );
    println!(
        "followed         unverified {} (through a reported obstacle {})",
        t.followed_unverified, t.followed_through_obstacle
    );
    println!("own check        max {:.2} ms", r.check_max_ms);
    println!("answer time      max {:.2} ms, {} after the deadline", t.answer_max_ms, t.late_answers);
    println!("without a plan   longest {:.0} ms", t.longest_without_plan_ms);
    println!(
        "stops            {} ({} with the team at rest off its goals), longest {:.0} ms, {:.0} ms in all",
        t.stops, t.halts, t.longest_stop_ms, t.stopped_ms
    );
    println!("tracking error   mean {:.4} m, max {:.4} m", r.mean_tracking_error_m, r.max_tracking_error_m);
    println!("goal sets        {} reached", r.goal_sets_reached);
    if let Some(lab) = &r.lab {
        println!(
            "lab              goals reached {} ({:.2} per robot-minute), goals changed mid-flight {}, gusts {}, walkers {}",
            lab.goals_reached, lab.goals_per_robot_minute, lab.goal_changes, lab.gusts, lab.walkers
        );
    }
    for f in &r.faults {
        println!(
            "fault {:<18} at {:>5.1} s: contacts {} + {} obstacle, closest {:.3}, unverified {}, longest without plan {:.0} ms, injected {} (rejected as expected {}), statuses {:?}",
            f.fault,
            f.at_s,
            f.tally.contacts,
            f.tally.obstacle_contacts,
            f.tally.closest_approach.unwrap_or(f64::NAN),
            f.tally.followed_unverified,
            f.tally.longest_without_plan_ms,
            f.tally.injected,
            f.tally.rejected_as_expected,
            f.tally.statuses
        );
    }
}
