//! The fault schedule of `flowopt demo --faults` (and `flowopt sim
//! --faults`): what a lab produces, injected at fixed times so that runs
//! can be repeated. The simulator injects the controller-side faults and
//! attributes what it measures to every fault's window; the demo injects
//! the process-side ones at the same times.

use flowopt_client::Reason;

/// Seconds after a fault ends that still count towards it.
pub const SETTLE_S: f64 = 5.0;

/// One kind of fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// The controller process restarts (new ports, sequences from 1) with
    /// the same goals; its robots brake meanwhile.
    ControllerRestart,
    /// The robots stand still with their goals set, whatever the plans say.
    Frozen,
    /// One snapshot reports robot 0 at 1e6 m/s.
    SpeedGlitch,
    /// One snapshot has a NaN position.
    NanState,
    /// One snapshot is stamped 0.
    ZeroTimestamp,
    /// One snapshot is stamped an hour ahead.
    FutureTimestamp,
    /// A second daemon is started for the same team.
    SecondDaemon,
    /// The daemon is killed with SIGKILL and started again.
    DaemonKill,
    /// A static obstacle appears on the held plan's path, ahead of a
    /// moving robot, for the fault's duration.
    ObstacleAppears,
    /// An obstacle walks across the team in flight at walking speed,
    /// reported with its velocity.
    ObstacleCrossing,
    /// A second controller for the same team starts (it must be refused).
    SecondController,
}

impl Fault {
    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Fault::ControllerRestart => "controller_restart",
            Fault::Frozen => "robots_frozen",
            Fault::SpeedGlitch => "speed_glitch",
            Fault::NanState => "nan_state",
            Fault::ZeroTimestamp => "timestamp_zero",
            Fault::FutureTimestamp => "timestamp_future",
            Fault::SecondDaemon => "second_daemon",
            Fault::DaemonKill => "daemon_sigkill",
            Fault::ObstacleAppears => "obstacle_appears",
            Fault::ObstacleCrossing => "obstacle_crossing",
            Fault::SecondController => "second_controller",
        }
    }

    /// For a fault that is one bad snapshot: the reason it must be
    /// rejected with.
    pub fn expected_rejection(self) -> Option<Reason> {
        match self {
            Fault::SpeedGlitch => Some(Reason::Implausible),
            Fault::NanState => Some(Reason::NonFinite),
            Fault::ZeroTimestamp | Fault::FutureTimestamp => Some(Reason::Clock),
            _ => None,
        }
    }

    /// Whether the demo (rather than the simulator) injects it.
    pub fn in_demo(self) -> bool {
        matches!(self, Fault::SecondDaemon | Fault::DaemonKill | Fault::SecondController)
    }
}

/// A fault at a time of the run.
#[derive(Debug, Clone, Copy)]
pub struct Scheduled {
    /// The fault.
    pub fault: Fault,
    /// Seconds from the start of the run.
    pub at_s: f64,
    /// How long it lasts (s; 0 for one event).
    pub lasts_s: f64,
}

impl Scheduled {
    /// Whether `t` seconds into the run fall in the fault's window (the
    /// fault and [`SETTLE_S`] after it).
    pub fn covers(&self, t: f64) -> bool {
        t >= self.at_s && t < self.at_s + self.lasts_s + SETTLE_S
    }
}

/// The schedule: one of each, in 100 s.
pub const SCHEDULE: [Scheduled; 11] = [
    Scheduled { fault: Fault::ControllerRestart, at_s: 8.0, lasts_s: 0.5 },
    Scheduled { fault: Fault::Frozen, at_s: 18.0, lasts_s: 5.0 },
    Scheduled { fault: Fault::SpeedGlitch, at_s: 32.0, lasts_s: 0.0 },
    Scheduled { fault: Fault::NanState, at_s: 36.0, lasts_s: 0.0 },
    Scheduled { fault: Fault::ZeroTimestamp, at_s: 40.0, lasts_s: 0.0 },
    Scheduled { fault: Fault::FutureTimestamp, at_s: 44.0, lasts_s: 0.0 },
    Scheduled { fault: Fault::SecondDaemon, at_s: 50.0, lasts_s: 0.0 },
    Scheduled { fault: Fault::DaemonKill, at_s: 60.0, lasts_s: 0.0 },
    Scheduled { fault: Fault::ObstacleAppears, at_s: 70.0, lasts_s: 6.0 },
    Scheduled { fault: Fault::ObstacleCrossing, at_s: 82.0, lasts_s: 6.0 },
    Scheduled { fault: Fault::SecondController, at_s: 95.0, lasts_s: 0.0 },
];
