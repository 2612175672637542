//! Cold plans on their own threads, one per method (the from-scratch
//! optimiser, and the learned pipeline when the team has weights), racing
//! on the cores: every request goes to every method, the first verified
//! plan wins and the others are cancelled. A request that misses its
//! snapshot's deadline keeps running (anytime) until it verifies, fails or
//! is cancelled, or its budget runs out; the team planner decides whether
//! its plan is still usable when it arrives.

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::{JoinHandle, Thread};
use std::time::{Duration, Instant};

use crossbeam::channel::{Receiver, Sender, TrySendError, bounded, unbounded};
use flowopt_models::pipeline::{LearnedPlanner, PipelineSettings};
use flowopt_planner::am::{Budget, EngineSet, Stop};
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::Problem;
use tracing::{info_span, warn};

use crate::planning::Stages;

/// A way of making cold plans.
#[derive(Debug)]
pub(crate) enum Method {
    /// The from-scratch optimiser, one engine per obstacle count.
    Optimiser(EngineSet),
    /// The learned pipeline with its safety filters.
    Learned {
        /// The networks.
        planner: Box<LearnedPlanner>,
        /// Candidates, steps, top-k.
        settings: PipelineSettings,
        /// Its safety filters, one per obstacle count.
        filters: EngineSet,
        /// Plans made so far (seeds the flow noise).
        plans: u64,
    },
}

impl Method {
    fn name(&self) -> &'static str {
        match self {
            Method::Optimiser(_) => "optimiser",
            Method::Learned { .. } => "learned",
        }
    }

    /// Plans `problem` within `budget`; the plan only if it verified.
    fn plan(&mut self, problem: &Problem, budget: &Budget<'_>) -> ColdOutcome {
        let obstacles = problem.obstacles.len();
        let started = Instant::now();
        match self {
            Method::Optimiser(set) => {
                let _span = info_span!("optimise").entered();
                let outcome = set.get(obstacles).and_then(|engine| {
                    let prepared = engine.prepare(problem, None).ok()?;
                    Some((engine, engine.solve_prepared_within(&prepared, budget)))
                });
                let stages = Stages { optimise: started.elapsed(), ..Stages::default() };
                match outcome {
                    Some((engine, o)) => ColdOutcome {
                        plan: (o.stop == Stop::Verified).then(|| engine.plan(o.state.xi)),
                        primal: o.primal,
                        iterations: o.iterations,
                        candidates: 1,
                        stages,
                    },
                    None => ColdOutcome::failed(stages),
                }
            }
            Method::Learned { planner, settings, filters, plans } => {
                let _span = info_span!("learned").entered();
                *plans += 1;
                let Some(sf) = filters.get(obstacles) else { return ColdOutcome::failed(Stages::default()) };
                let Ok(out) = planner.model().plan(problem, sf, settings, *plans, budget) else {
                    return ColdOutcome::failed(Stages::default());
                };
                let ms = |ms: f64| Duration::from_secs_f64((ms * 1e-3).max(0.0));
                let stages = Stages {
                    sample: ms(out.times.sample_ms),
                    rank: ms(out.times.rank_ms),
                    init: ms(out.times.init_ms),
                    filter: ms(out.times.filter_ms),
                    select: ms(out.times.select_ms),
                    ..Stages::default()
                };
                let candidates = out.refined.len();
                let iterations = out.refined.iter().map(|r| r.outcome.iterations).sum();
                let chosen = &out.refined[out.chosen];
                ColdOutcome {
                    plan: out.verified.then(|| sf.plan(chosen.outcome.state.xi.clone())),
                    primal: chosen.outcome.primal,
                    iterations,
                    candidates,
                    stages,
                }
            }
        }
    }
}

/// What one method made of one request.
#[derive(Debug, Clone)]
pub(crate) struct ColdOutcome {
    /// The plan, when it verified.
    pub plan: Option<JointPlan>,
    /// Its primal residual (m).
    pub primal: f64,
    /// Iterations spent.
    pub iterations: usize,
    /// Candidates refined.
    pub candidates: usize,
    /// Stage times.
    pub stages: Stages,
}

impl ColdOutcome {
    fn failed(stages: Stages) -> Self {
        Self { plan: None, primal: f64::NAN, iterations: 0, candidates: 0, stages }
    }
}

/// A request: plan `problem`, measured at `origin_ns` in snapshot `sequence`.
#[derive(Debug, Clone)]
pub(crate) struct ColdRequest {
    /// Its id (cancelled when the planner's current id moves on).
    pub id: u64,
    /// The problem, from the measured state.
    pub problem: Problem,
    /// Its time origin.
    pub origin_ns: u64,
    /// The snapshot it came from.
    pub sequence: u64,
}

/// One method's answer to a request.
#[derive(Debug)]
pub(crate) struct ColdResult {
    /// The request answered.
    pub request: ColdRequest,
    /// Which method.
    pub method: &'static str,
    /// What it made.
    pub outcome: ColdOutcome,
}

/// One method's thread and the slot its requests wait in.
struct Lane {
    requests: Sender<ColdRequest>,
    /// A second receiver, to replace a request not yet started.
    evict: Receiver<ColdRequest>,
    thread: Option<JoinHandle<()>>,
}

/// The cold-planning threads of one team.
pub(crate) struct ColdPlanner {
    lanes: Vec<Lane>,
    /// The request every lane works for; any other is cancelled.
    current: Arc<AtomicU64>,
    next_id: u64,
    results: Receiver<ColdResult>,
    /// The thread waiting in [`ColdPlanner::wait_until`], woken by every
    /// result.
    waiter: Arc<Mutex<Option<Thread>>>,
}

impl std::fmt::Debug for ColdPlanner {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ColdPlanner").field("lanes", &self.lanes.len()).finish()
    }
}

impl ColdPlanner {
    /// Starts one thread per method; each request may run for `budget`.
    pub fn start(team: &str, methods: Vec<Method>, budget: Duration) -> Self {
        let current = Arc::new(AtomicU64::new(0));
        let waiter = Arc::new(Mutex::new(None));
        let (results_tx, results) = unbounded();
        let lanes = methods
            .into_iter()
            .map(|method| {
                let (requests, rx) = bounded::<ColdRequest>(1);
                let evict = rx.clone();
                let (current, results_tx) = (Arc::clone(&current), results_tx.clone());
                let results = Outbox { results: results_tx, waiter: Arc::clone(&waiter) };
                let name = format!("cold-{}-{}", method.name(), team);
                let thread = std::thread::Builder::new()
                    .name(name)
                    .spawn(move || serve_lane(method, rx, current, results, budget))
                    .map_err(|e| warn!("cannot start a cold-planning thread: {e}"))
                    .ok();
                Lane { requests, evict, thread }
            })
            .collect();
        Self { lanes, current, next_id: 0, results, waiter }
    }

    /// The next result, waiting for one until `until` at most. Unlike a
    /// channel's blocking receive, which backs off by yielding the core
    /// (and a busy cold thread can then keep it for a scheduler tick, some
    /// milliseconds), this sleeps until a result or `until` wakes it.
    pub fn wait_until(&self, until: Instant) -> Option<ColdResult> {
        if let Ok(mut waiter) = self.waiter.lock() {
            *waiter = Some(std::thread::current());
        }
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

    /// Sends `problem` to every method, cancelling whatever they were
    /// doing; returns the request's id.
    pub fn submit(&mut self, problem: &Problem, origin_ns: u64, sequence: u64) -> u64 {
        self.next_id += 1;
        let id = self.next_id;
        self.current.store(id, Ordering::Relaxed);
        let request = ColdRequest { id, problem: problem.clone(), origin_ns, sequence };
        for lane in &self.lanes {
            if let Err(TrySendError::Full(r)) = lane.requests.try_send(request.clone()) {
                let _ = lane.evict.try_recv();
                let _ = lane.requests.try_send(r);
            }
        }
        id
    }

    /// Cancels the current request.
    pub fn cancel(&self) {
        self.current.store(0, Ordering::Relaxed);
    }

    /// The methods racing on every request.
    pub fn methods(&self) -> usize {
        self.lanes.len()
    }

    /// The results, in the order the methods finish.
    pub fn results(&self) -> &Receiver<ColdResult> {
        &self.results
    }
}

impl Drop for ColdPlanner {
    fn drop(&mut self) {
        self.cancel();
        for lane in &mut self.lanes {
            // Disconnect the lane: its thread ends after its current request.
            let (dead, _) = bounded(0);
            lane.requests = dead;
            while lane.evict.try_recv().is_ok() {}
        }
        for lane in &mut self.lanes {
            if let Some(thread) = lane.thread.take() {
                let _ = thread.join();
            }
        }
    }
}

/// How much nicer (Linux `nice`) than the worker the cold lanes run: the
/// worker, which must publish every answer by its deadline, preempts them
/// as soon as it wakes instead of waiting for a time slice on a busy core.
const LANE_NICENESS: i32 = 5;

/// Lowers the calling thread's priority by [`LANE_NICENESS`] (best effort).
fn be_nicer() {
    // SAFETY: plain syscalls on the calling thread.
    unsafe {
        let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
        let now = libc::getpriority(libc::PRIO_PROCESS, tid);
        if libc::setpriority(libc::PRIO_PROCESS, tid, now + LANE_NICENESS) != 0 {
            warn!("cannot lower a cold-planning thread's priority");
        }
    }
}

/// Where a lane's results go: the channel, and a wake-up for the thread
/// waiting on it.
struct Outbox {
    results: Sender<ColdResult>,
    waiter: Arc<Mutex<Option<Thread>>>,
}

impl Outbox {
    fn send(&self, result: ColdResult) -> Result<(), ()> {
        self.results.send(result).map_err(|_| ())?;
        if let Ok(waiter) = self.waiter.lock()
            && let Some(thread) = waiter.as_ref()
        {
            thread.unpark();
        }
        Ok(())
    }
}

/// One lane's loop: plans every request that is still current.
fn serve_lane(
    mut method: Method,
    requests: Receiver<ColdRequest>,
    current: Arc<AtomicU64>,
    results: Outbox,
    budget: Duration,
) {
    be_nicer();
    while let Ok(request) = requests.recv() {
        let id = request.id;
        if current.load(Ordering::Relaxed) != id {
            continue;
        }
        let cancelled = || current.load(Ordering::Relaxed) != id;
        let deadline = Instant::now() + budget;
        let outcome = method.plan(&request.problem, &Budget::until(deadline).or_cancelled(&cancelled));
        if results.send(ColdResult { request, method: method.name(), outcome }).is_err() {
            break;
        }
    }
}
