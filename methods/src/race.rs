//! The portfolio race (OMPL's `ParallelPlan`): every member plans every
//! request on a thread of its own that lives as long as the race; the
//! first verified plan within the team's limits
//! ([`Planned::within_limits`]) wins and the others are cancelled.
//!
//! The daemon uses it anytime: [`Race::submit`] returns at once, results
//! arrive on [`Race::results`] (or [`Race::wait_until`]) in the order the
//! members finish, and a request that misses its snapshot's deadline keeps
//! running until it verifies, fails, is cancelled or its budget runs out.
//! The command line calls it as a [`Planner`]: [`Race::plan`] waits for the
//! first verified plan within the limits (or every member's end) and
//! returns it with the time to it; the losers are stopped before it
//! returns. (The daemon applies the limits itself, stretching plans from
//! rest.)

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};

use crossbeam::channel::{Receiver, Sender, TrySendError, bounded, unbounded};
use std::thread::{JoinHandle, Thread};
use std::time::{Duration, Instant};

use flowopt_planner::am::Budget;
use flowopt_planner::method::{PlanError, Planned, Planner};
use flowopt_planner::problem::{Problem, Team};
use tracing::warn;

/// A request: plan `problem` with noise seeded by `seed`.
#[derive(Debug, Clone)]
pub struct Request {
    /// Its id (cancelled when the race's current id moves on).
    pub id: u64,
    /// The problem.
    pub problem: Problem,
    /// The noise seed.
    pub seed: u64,
    /// The measurement the problem comes from (the daemon's snapshot
    /// timestamp; 0 elsewhere).
    pub origin_ns: u64,
    /// The snapshot's sequence (0 elsewhere).
    pub sequence: u64,
    /// Stop by then (besides the race's own budget).
    pub deadline: Option<Instant>,
}

/// One member's answer to a request.
#[derive(Debug)]
pub struct RaceResult {
    /// The request answered.
    pub request: Request,
    /// The member.
    pub by: &'static str,
    /// What it made.
    pub outcome: Result<Planned, PlanError>,
}

/// What a lane is asked.
enum Job {
    Plan(Request),
    Ready(Team, usize, Sender<Result<(), PlanError>>),
}

/// One member's thread and the slot its jobs wait in.
struct Lane {
    jobs: Sender<Job>,
    /// A second receiver, to replace a request not yet started.
    evict: Receiver<Job>,
    thread: Option<JoinHandle<()>>,
}

/// Planners racing on threads of their own.
pub struct Race {
    lanes: Vec<Lane>,
    /// The request every lane works for; any other is cancelled.
    current: Arc<AtomicU64>,
    next_id: u64,
    results: Receiver<RaceResult>,
    /// The thread that waits in [`Race::wait_until`] (the first that
    /// does), woken by every result. Set once and read without a lock, so
    /// that a racing thread preempted while waking it cannot hold up a
    /// waiter of higher priority.
    waiter: Arc<OnceLock<Thread>>,
}

impl std::fmt::Debug for Race {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Race").field("members", &self.lanes.len()).finish()
    }
}

/// Where a lane's results go: the channel, and a wake-up for the thread
/// waiting on it.
struct Outbox {
    results: Sender<RaceResult>,
    waiter: Arc<OnceLock<Thread>>,
}

impl Outbox {
    fn send(&self, result: RaceResult) -> Result<(), ()> {
        self.results.send(result).map_err(|_| ())?;
        if let Some(thread) = self.waiter.get() {
            thread.unpark();
        }
        Ok(())
    }
}

impl Race {
    /// Starts one thread per member, named after `name` and the member;
    /// each request may run for `budget` at most (besides its own
    /// deadline); `on_start` runs first on every lane thread (the daemon
    /// lowers the lanes' priority there).
    pub fn start(name: &str, members: Vec<Box<dyn Planner>>, budget: Option<Duration>, on_start: fn()) -> Self {
        let current = Arc::new(AtomicU64::new(0));
        let waiter = Arc::new(OnceLock::new());
        let (results_tx, results) = unbounded();
        let lanes = members
            .into_iter()
            .map(|member| {
                let (jobs, rx) = bounded::<Job>(1);
                let evict = rx.clone();
                let outbox = Outbox { results: results_tx.clone(), waiter: Arc::clone(&waiter) };
                let current = Arc::clone(&current);
                let thread = std::thread::Builder::new()
                    .name(format!("race-{}-{name}", member.name()))
                    .spawn(move || {
                        on_start();
                        serve_lane(member, &rx, &current, &outbox, budget)
                    })
                    .map_err(|e| warn!("cannot start a racing thread: {e}"))
                    .ok();
                Lane { jobs, evict, thread }
            })
            .collect();
        Self { lanes, current, next_id: 0, results, waiter }
    }

    /// Sends `problem` to every member, cancelling whatever they were
    /// doing; returns the request's id.
    pub fn submit(&mut self, problem: &Problem, seed: u64, origin_ns: u64, sequence: u64) -> u64 {
        self.submit_until(problem, seed, origin_ns, sequence, None)
    }

    fn submit_until(
        &mut self,
        problem: &Problem,
        seed: u64,
        origin_ns: u64,
        sequence: u64,
        deadline: Option<Instant>,
    ) -> u64 {
        self.next_id += 1;
        let id = self.next_id;
        self.current.store(id, Ordering::Release);
        let request = Request { id, problem: problem.clone(), seed, origin_ns, sequence, deadline };
        for lane in &self.lanes {
            if let Err(TrySendError::Full(job)) = lane.jobs.try_send(Job::Plan(request.clone())) {
                // Replace the request the lane has not started.
                let _ = lane.evict.try_recv();
                let _ = lane.jobs.try_send(job);
            }
        }
        id
    }

    /// Cancels the current request.
    pub fn cancel(&self) {
        self.current.store(0, Ordering::Release);
    }

    /// The members racing on every request.
    pub fn members(&self) -> usize {
        self.lanes.len()
    }

    /// The results, in the order the members finish.
    pub fn results(&self) -> &Receiver<RaceResult> {
        &self.results
    }

    /// The next result, waiting for one until `until` at most. It sleeps
    /// until a result or `until` wakes it (a channel's blocking receive
    /// may yield the core to the racing threads for a scheduler slice).
    /// Results wake the first thread that waited; another wakes at `until`.
    pub fn wait_until(&self, until: Instant) -> Option<RaceResult> {
        let _ = self.waiter.get_or_init(std::thread::current);
        loop {
            if let Ok(result) = self.results.try_recv() {
                return Some(result);
            }
            let now = Instant::now();
            if now >= until {
                return None;
            }
            std::thread::park_timeout(until - now);
        }
    }
}

impl Planner for Race {
    fn name(&self) -> &'static str {
        "race"
    }

    fn ready(&mut self, team: &Team, obstacles: usize) -> Result<(), PlanError> {
        for lane in &self.lanes {
            let (tx, rx) = bounded(1);
            lane.jobs.send(Job::Ready(team.clone(), obstacles, tx)).map_err(|_| gone())?;
            rx.recv().map_err(|_| gone())??;
        }
        Ok(())
    }

    /// The first verified plan within the limits, or, if none is, the
    /// first verified plan, else the optimiser's plan (else the first
    /// member's); the others are cancelled and stopped before it returns.
    /// The caller's deadline and cancellation apply.
    fn plan(&mut self, problem: &Problem, budget: &Budget<'_>, seed: u64) -> Result<Planned, PlanError> {
        let started = Instant::now();
        let id = self.submit_until(problem, seed, 0, 0, budget.deadline);
        let mut outstanding = self.lanes.len();
        let (mut winner, mut others): (Option<Planned>, Vec<Result<Planned, PlanError>>) = (None, Vec::new());
        while outstanding > 0 {
            let slice = Instant::now() + Duration::from_millis(1);
            let Some(result) = self.wait_until(slice) else {
                if budget.cancelled.is_some_and(|c| c()) {
                    self.cancel();
                }
                continue;
            };
            if result.request.id != id {
                continue;
            }
            outstanding -= 1;
            match result.outcome {
                Ok(mut planned) if planned.verified() && planned.within_limits(problem) && winner.is_none() => {
                    self.cancel();
                    planned.wall = started.elapsed();
                    winner = Some(planned);
                }
                other => others.push(other),
            }
        }
        if let Some(planned) = winner {
            return Ok(planned);
        }
        // None within the limits: a verified plan over them (a daemon
        // refuses it, a benchmark counts it), else the optimiser's last
        // iterate, else any.
        let verified = others.iter().position(|o| o.as_ref().is_ok_and(Planned::verified));
        let position = |by: &str| others.iter().position(|o| o.as_ref().is_ok_and(|p| p.by == by));
        let pick =
            verified.or_else(|| position("optimiser")).or_else(|| others.iter().position(Result::is_ok)).unwrap_or(0);
        if others.is_empty() {
            return Err(PlanError::Failed("the race has no members".into()));
        }
        others.swap_remove(pick).map(|mut p| {
            p.wall = started.elapsed();
            p
        })
    }
}

impl Drop for Race {
    fn drop(&mut self) {
        self.cancel();
        for lane in &mut self.lanes {
            // Hang up: the lane's thread ends after its current job.
            let (dead, _) = bounded(0);
            lane.jobs = dead;
            while lane.evict.try_recv().is_ok() {}
        }
        for lane in &mut self.lanes {
            if let Some(thread) = lane.thread.take() {
                let _ = thread.join();
            }
        }
    }
}

fn gone() -> PlanError {
    PlanError::Failed("a racing thread is gone".into())
}

/// One lane's loop: plans every request that is still current.
fn serve_lane(
    mut member: Box<dyn Planner>,
    jobs: &Receiver<Job>,
    current: &AtomicU64,
    results: &Outbox,
    budget: Option<Duration>,
) {
    loop {
        let request = match jobs.recv() {
            Ok(Job::Plan(request)) => request,
            Ok(Job::Ready(team, obstacles, reply)) => {
                let _ = reply.send(member.ready(&team, obstacles));
                continue;
            }
            Err(_) => return,
        };
        let id = request.id;
        if current.load(Ordering::Acquire) != id {
            // Cancelled before it started: said, so that a waiter counting
            // the members' answers is not left waiting.
            let outcome = Err(PlanError::Cancelled);
            if results.send(RaceResult { request, by: member.name(), outcome }).is_err() {
                return;
            }
            continue;
        }
        let cancelled = || current.load(Ordering::Acquire) != id;
        let deadline = match (request.deadline, budget) {
            (Some(d), Some(b)) => Some(d.min(Instant::now() + b)),
            (d, b) => d.or(b.map(|b| Instant::now() + b)),
        };
        let within = Budget { deadline, cancelled: Some(&cancelled) };
        let outcome = member.plan(&request.problem, &within, request.seed);
        if results.send(RaceResult { request, by: member.name(), outcome }).is_err() {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use flowopt_planner::am::Stop;
    use flowopt_planner::method::Stages;
    use flowopt_planner::plan::JointPlan;
    use flowopt_planner::problem::Dim;
    use flowopt_planner::scenario::RandomScenario;

    /// A member that takes `delay` (checking its budget meanwhile) and
    /// returns a plan whose coefficients are the seed, verified or not.
    struct Fake {
        name: &'static str,
        delay: Duration,
        verifies: bool,
        /// Set when it noticed it was cancelled.
        cancelled: Arc<AtomicU64>,
        /// It ignores its budget (a planner between two checks).
        stubborn: bool,
        /// Its coefficients alternate by a metre (accelerations far over
        /// any limit) instead of all being the seed.
        rough: bool,
    }

    impl Planner for Fake {
        fn name(&self) -> &'static str {
            self.name
        }

        fn ready(&mut self, _team: &Team, _obstacles: usize) -> Result<(), PlanError> {
            Ok(())
        }

        fn plan(&mut self, problem: &Problem, budget: &Budget<'_>, seed: u64) -> Result<Planned, PlanError> {
            let until = Instant::now() + self.delay;
            let mut stop = if self.verifies { Stop::Verified } else { Stop::IterationCap };
            while Instant::now() < until {
                if let Some(s) = budget.spent().filter(|_| !self.stubborn) {
                    self.cancelled.fetch_add(1, Ordering::AcqRel);
                    stop = s;
                    break;
                }
                std::thread::sleep(Duration::from_micros(200));
            }
            let n = problem.team.dim.axes() * problem.team.robots * (problem.team.degree + 1);
            let coefficient = |k: usize| if self.rough { (k % 2) as f64 } else { seed as f64 };
            Ok(Planned {
                plan: JointPlan::new(&problem.team, (0..n).map(coefficient).collect()),
                stop,
                primal: 0.0,
                iterations: 1,
                run_iterations: 1,
                candidates: 1,
                stages: Stages::default(),
                wall: Duration::ZERO,
                by: self.name,
                start: None,
            })
        }
    }

    fn fake(name: &'static str, ms: u64, verifies: bool, cancelled: &Arc<AtomicU64>) -> Box<dyn Planner> {
        Box::new(Fake {
            name,
            delay: Duration::from_millis(ms),
            verifies,
            cancelled: Arc::clone(cancelled),
            stubborn: false,
            rough: false,
        })
    }

    fn problem() -> Problem {
        RandomScenario::new(Team::default_for(Dim::Two, 2)).generate(1).unwrap()
    }

    #[test]
    fn a_verified_plan_from_motion_over_the_limit_loses_to_one_within_it() {
        let cancelled = Arc::new(AtomicU64::new(0));
        let rough = Box::new(Fake {
            name: "rough",
            delay: Duration::from_millis(1),
            verifies: true,
            cancelled: Arc::clone(&cancelled),
            stubborn: false,
            rough: true,
        });
        let members: Vec<Box<dyn Planner>> = vec![rough, fake("smooth", 50, true, &cancelled)];
        let mut race = Race::start("test", members, None, || {});
        let mut moving = problem();
        moving.team.max_acceleration = Some(3.0);
        moving.starts[0].velocity.x = 0.5;
        let planned = race.plan(&moving, &Budget::unlimited(), 7).unwrap();
        assert_eq!(planned.by, "smooth", "the first verified plan is over the limit");
        // From rest it would be stretched in time: the first one wins.
        let mut rest = moving.clone();
        rest.starts[0].velocity.x = 0.0;
        assert_eq!(race.plan(&rest, &Budget::unlimited(), 7).unwrap().by, "rough");
        // Without a limit, too.
        moving.team.max_acceleration = None;
        assert_eq!(race.plan(&moving, &Budget::unlimited(), 7).unwrap().by, "rough");
    }

    #[test]
    fn the_first_verified_plan_wins_and_the_loser_is_cancelled() {
        let cancelled = Arc::new(AtomicU64::new(0));
        let members = vec![fake("slow", 2000, true, &cancelled), fake("fast", 5, true, &cancelled)];
        let mut race = Race::start("test", members, None, || {});
        let planned = race.plan(&problem(), &Budget::unlimited(), 7).unwrap();
        assert_eq!((planned.by, planned.verified()), ("fast", true));
        assert_eq!(cancelled.load(Ordering::Acquire), 1, "the slow member was cancelled");
    }

    #[test]
    fn a_member_that_starts_a_request_after_it_was_won_still_answers() {
        let cancelled = Arc::new(AtomicU64::new(0));
        let busy = Fake {
            name: "busy",
            delay: Duration::from_millis(50),
            verifies: true,
            cancelled: Arc::clone(&cancelled),
            stubborn: true,
            rough: false,
        };
        let mut race = Race::start("test", vec![fake("fast", 1, true, &cancelled), Box::new(busy)], None, || {});
        // The busy member is still on an earlier request when the next one
        // is won: it takes that one up cancelled, and says so.
        race.submit(&problem(), 1, 0, 0);
        std::thread::sleep(Duration::from_millis(5));
        let planned = race.plan(&problem(), &Budget::unlimited(), 7).unwrap();
        assert_eq!(planned.by, "fast");
    }

    #[test]
    fn a_fast_plan_that_does_not_verify_does_not_win() {
        let cancelled = Arc::new(AtomicU64::new(0));
        let members = vec![fake("unverified", 1, false, &cancelled), fake("verified", 30, true, &cancelled)];
        let mut race = Race::start("test", members, None, || {});
        let planned = race.plan(&problem(), &Budget::unlimited(), 7).unwrap();
        assert_eq!(planned.by, "verified");
        // Neither verifies: the optimiser's plan, else the first member's.
        let cancelled = Arc::new(AtomicU64::new(0));
        let members = vec![fake("learned", 1, false, &cancelled), fake("optimiser", 5, false, &cancelled)];
        let mut race = Race::start("test", members, None, || {});
        let planned = race.plan(&problem(), &Budget::unlimited(), 7).unwrap();
        assert_eq!((planned.by, planned.verified()), ("optimiser", false));
    }

    #[test]
    fn results_are_deterministic_under_seeds() {
        let cancelled = Arc::new(AtomicU64::new(0));
        let members = vec![fake("a", 100, true, &cancelled), fake("b", 2, true, &cancelled)];
        let mut race = Race::start("test", members, None, || {});
        let p = problem();
        let first = race.plan(&p, &Budget::unlimited(), 11).unwrap();
        let again = race.plan(&p, &Budget::unlimited(), 11).unwrap();
        let other = race.plan(&p, &Budget::unlimited(), 12).unwrap();
        assert_eq!((first.by, first.plan.coeffs.clone()), (again.by, again.plan.coeffs));
        assert_ne!(first.plan.coeffs, other.plan.coeffs, "the seed reaches the members");
    }

    #[test]
    fn a_request_keeps_running_past_its_callers_wait_and_a_new_one_cancels_it() {
        let cancelled = Arc::new(AtomicU64::new(0));
        let mut race = Race::start("test", vec![fake("slow", 50, true, &cancelled)], None, || {});
        let first = race.submit(&problem(), 1, 10, 1);
        assert!(race.wait_until(Instant::now() + Duration::from_millis(5)).is_none(), "not yet");
        let result = race.wait_until(Instant::now() + Duration::from_secs(10)).expect("it finished later");
        assert_eq!((result.request.id, result.request.sequence), (first, 1));
        // A newer request cancels the one running.
        race.submit(&problem(), 2, 20, 2);
        std::thread::sleep(Duration::from_millis(5));
        let newest = race.submit(&problem(), 3, 30, 3);
        let mut seen = Vec::new();
        while let Some(r) = race.wait_until(Instant::now() + Duration::from_secs(10)) {
            seen.push((r.request.id, r.outcome.unwrap().stop));
            if r.request.id == newest {
                break;
            }
        }
        assert_eq!(seen.last(), Some(&(newest, Stop::Verified)));
        assert!(seen.iter().all(|(id, stop)| *id == newest || *stop == Stop::Cancelled), "{seen:?}");
    }
}
