//! One team's planner and the followability contract: every snapshot gets
//! an answer that says which trajectory the controllers are to follow from
//! now on, and that trajectory is always one this planner verified from a
//! state consistent with the measured one and against the world the newest
//! accepted snapshot reports, or there is none. It knows nothing of the
//! wire: the daemon's worker converts snapshots into problems and writes
//! the replies.
//!
//! - **The world.** The newest accepted measurement: the robots and the
//!   obstacles (static, or moving at their reported velocities) of the
//!   newest snapshot that passed the value checks, even when its task (its
//!   goals) could not be planned. Every followable answer is checked
//!   against it before it is published ([`TeamPlanner::followable`]): the
//!   measured robots within `follow_tolerance_m` of the plan, and the
//!   plan's rest (at least the stopping horizon) clear of the obstacles
//!   with the plan's own buffer ([`Recheck`]).
//! - **Held plan.** The last verified plan published, with its own time
//!   origin: what the controllers follow. A late or failed computation never
//!   replaces it; it is re-issued ([`Follow::Held`]) while it passes the
//!   check above. One that no longer does is replaced at once by a stopping
//!   plan verified against that world, or by nothing.
//! - **Where new plans start.** A new plan starts each robot that follows
//!   the held plan (measured within the follow tolerance of it) where the
//!   held plan has it at the snapshot's time, with its velocity and
//!   acceleration ([`Held::anchored`]), and every other robot from its
//!   measurement: the plans the controllers follow join without a jump, a
//!   plan that comes late still starts where the robots are (they kept
//!   following the held one) up to the tracking error the follow tolerance
//!   allows, and one robot knocked off the plan leaves the others on it.
//! - **Warm start**, only from a plan the robots are on: when the goals are
//!   unchanged and the measured state is within `warm_tolerance_m` of the
//!   held plan at the snapshot's time, the held plan shifted in time
//!   ([`JointPlan::shifted`]) is the safety filter's sample against the
//!   newest obstacles; a verified result is the new plan.
//! - **A held plan that serves is kept.** When the warm start does not
//!   verify in time but the held plan leads to the same goals and passes
//!   the check, it is re-issued at once and no cold plan runs (none is
//!   needed, and a late one makes the robots jump by what two plans differ
//!   over its latency); 128 robots: the answers' p99 83-87 ms against
//!   117 ms, lost plans unchanged (docs/BENCHMARKS.md, "Threads").
//! - **Cold plan** otherwise (new goals, robots off the plan, an obstacle
//!   on it): the cold planner's methods race on their own threads
//!   ([`crate::cold`]) within the same deadline; the first verified plan
//!   within the limits wins (one over them is refused and leaves the
//!   others running; when none is left, the answer says [`Why::Limits`]).
//!   One that misses it keeps
//!   running; its plan is adopted as soon as it verifies if it passes the
//!   check against the newest world (the robots still at its start), else
//!   it becomes the sample of the next warm start.
//! - **Fallback** when nothing verified by the deadline: the held plan if it
//!   passes the check; else a verified stopping plan (every robot brought to
//!   rest along its motion, [`flowopt_planner::stopping`]; verified at the
//!   true sizes, without the tracking buffer; at the stopping horizon, else,
//!   when that plan is refused, at twice it), computed first, before any
//!   new plan is tried (within half the deadline), so that the answer is on
//!   time and has it; else nothing ([`Follow::Nothing`]).
//! - **No measurement.** A snapshot rejected before its task (bad header,
//!   clock, sequence or values) changes nothing: the held plan is re-issued
//!   while the newest accepted snapshot is at most `stale_after_ms` old
//!   ([`TeamPlanner::reissue`]), then nothing is.
//! - **Limits.** A plan exceeding the team's speed or acceleration limits
//!   is stretched in time when the robots start at rest (the paper's
//!   post-hoc time scaling) and refused otherwise ([`Why::Limits`]).

use std::time::{Duration, Instant};

use flowopt_methods::{Planned, Race, RaceResult};
use flowopt_planner::am::EngineSet;
use flowopt_planner::am::Recheck;
use flowopt_planner::plan::JointPlan;
use flowopt_planner::problem::{Problem, Team};
use flowopt_planner::route::Fitter;
use nalgebra::Vector3;
use tracing::debug;

use crate::answer::{Answer, Follow, Kind, Why};
use crate::held::{Candidate, Held, World, same_goals, seconds};
use crate::stops::Stops;

/// Time kept before the deadline to publish an answer: at least this, and
/// a twentieth of the deadline (the planners check their budget every few
/// iterations).
const PUBLISH_MARGIN: Duration = Duration::from_millis(1);

/// A cold request in flight.
#[derive(Debug, Clone)]
pub(crate) struct Pending {
    id: u64,
    goals: Vec<Vector3<f64>>,
    obstacles: usize,
    /// Methods that have not answered yet.
    outstanding: usize,
}

/// What is published if nothing new verifies in time.
#[derive(Debug)]
enum Fallback {
    /// The held plan, which passed the check against the newest world.
    Held,
    /// A stopping plan verified against it.
    Stop(Box<Candidate>),
    /// Nothing.
    Nothing,
}

/// The team's deadline and tolerances (its speed and acceleration limits
/// are the team's own: `Team::max_speed`, `Team::max_acceleration`).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Rules {
    /// The time an answer may take from its snapshot's arrival.
    pub(crate) deadline: Duration,
    /// Robots within this distance (m) of a plan follow it.
    pub(crate) follow_tolerance: f64,
    /// Robots within this distance (m) of the held plan are warm-started.
    pub(crate) warm_tolerance: f64,
    /// How old the newest accepted snapshot may be for a plan to be
    /// re-issued without a newer one (ns).
    pub(crate) stale_after_ns: u64,
    /// How far ahead (s) a followable plan is checked against the newest
    /// world, robots resting at its end ([`TeamConfig::obstacle_check_s`]).
    pub(crate) check_window: f64,
}

/// A team's preloaded engines and its planning state.
#[derive(Debug)]
pub struct TeamPlanner {
    pub(crate) team: Team,
    pub(crate) rules: Rules,
    /// Warm-start safety filters, one per obstacle count.
    pub(crate) filters: EngineSet,
    /// The same holding the speed and acceleration limits in their
    /// iteration: they repair a warm plan the filters left over them.
    pub(crate) limited_filters: EngineSet,
    /// Stopping plans' engines, one set per horizon, in the order tried.
    pub(crate) stops: Vec<Stops>,
    pub(crate) fitter: Fitter,
    /// The obstacle checks of held plans against the newest world: plans
    /// to the goals with the tracking buffer, stopping plans without.
    pub(crate) recheck_goals: Recheck,
    pub(crate) recheck_stops: Recheck,
    pub(crate) cold: Race,
    pub(crate) held: Option<Held>,
    pub(crate) newest: Option<World>,
    pub(crate) pending: Option<Pending>,
    /// A verified cold plan whose start the robots had left: the next
    /// warm start's sample.
    pub(crate) fresh: Option<Candidate>,
}

impl TeamPlanner {
    /// The team.
    pub fn team(&self) -> &Team {
        &self.team
    }

    /// The time an answer may take from the arrival of its snapshot.
    pub fn deadline(&self) -> Duration {
        self.rules.deadline
    }

    /// The plan the controllers follow, if any.
    pub fn held(&self) -> Option<&Held> {
        self.held.as_ref()
    }

    /// The newest accepted snapshot's sequence and timestamp.
    pub fn newest(&self) -> Option<(u64, u64)> {
        self.newest.as_ref().map(|n| (n.sequence, n.origin_ns))
    }

    /// Where late cold plans arrive; hand each to [`Self::on_cold`].
    pub(crate) fn cold_results(&self) -> crossbeam::channel::Receiver<RaceResult> {
        self.cold.results().clone()
    }

    /// Whether `held` may be followed in `world`: the measured robots
    /// within `follow_tolerance_m` of it ([`Why::NotFollowing`]) and its
    /// rest, and at least the stopping horizon, clear of the world's
    /// obstacles as they move ([`Why::WorldChanged`]).
    fn followable(&self, held: &Held, world: &World) -> Result<(), Why> {
        self.may_follow(&held.plan, held.origin_ns, held.kind, world)
    }

    /// [`Self::followable`] for `plan` of `kind` with its origin at `origin_ns`.
    fn may_follow(&self, plan: &JointPlan, origin_ns: u64, kind: Kind, world: &World) -> Result<(), Why> {
        let elapsed = seconds(origin_ns, world.origin_ns);
        if plan.deviation(elapsed, &world.problem.starts) > self.rules.follow_tolerance {
            return Err(Why::NotFollowing);
        }
        let recheck = match kind {
            Kind::Goals => &self.recheck_goals,
            Kind::Stopping => &self.recheck_stops,
        };
        let elapsed = elapsed.max(0.0);
        let window = (plan.horizon - elapsed).max(self.rules.check_window);
        if !recheck.clear(plan, elapsed, window, &world.problem.obstacles) {
            return Err(Why::WorldChanged);
        }
        Ok(())
    }

    /// Half the deadline from now: the most one step of an answer (the
    /// stopping plan, the warm replan) or a late cold result's repair may
    /// take, so that another step keeps time.
    fn half_deadline_from_now(&self) -> Instant {
        Instant::now() + self.rules.deadline / 2
    }

    /// The instant planning for an answer due at `deadline` must end.
    fn until(&self, deadline: Instant) -> Instant {
        let margin = PUBLISH_MARGIN.max(self.rules.deadline / 20);
        deadline.checked_sub(margin).unwrap_or(deadline)
    }

    /// Answers an accepted snapshot: `problem` (validated, of this team),
    /// measured at `origin_ns` in snapshot `sequence`, by `deadline`.
    pub fn answer(&mut self, problem: Problem, origin_ns: u64, sequence: u64, deadline: Instant) -> Answer {
        let world = World { problem, origin_ns, sequence };
        self.newest = Some(world.clone());
        let until = self.until(deadline);
        let mut answer = Answer::new(Follow::Nothing, Why::DeadlineMissed);
        let checked = self.held.as_ref().map(|h| self.followable(h, &world));
        let deviation = self.held.as_ref().map(|h| h.deviation(&world.problem, origin_ns));
        let mut why = Why::DeadlineMissed;

        // The held plan leads to these goals.
        let to_goals =
            self.held.as_ref().is_some_and(|h| h.kind == Kind::Goals && same_goals(&h.goals, &world.problem));
        // Warm start from the held plan, if the robots are on it (against
        // the obstacles as they are now).
        let warm_from =
            self.held.as_ref().filter(|_| to_goals && deviation.is_some_and(|d| d <= self.rules.warm_tolerance));
        // New plans start where the held plan has each robot that follows
        // it, the others from their measurement.
        let anchored = self.held.as_ref().map(|h| h.anchored(&world, self.rules.follow_tolerance));
        let start = anchored.as_ref().unwrap_or(&world);
        // The fallback, made before anything else can take the time: the
        // held plan if it may be followed, else a stopping plan from the
        // measurement (a few iterations as a rule; within half the
        // deadline, so that the warm replan keeps its half; the cold
        // threads have the cores meanwhile). Made after the warm replan and
        // the repair of a left cold plan instead, it was left no time in 3
        // of the 19 `NoPlan` answers of a 64-robot lab run, a walker closing
        // in (docs/experiments/2026-11-28-lab64-walker-contacts.md).
        let fallback = match checked {
            Some(Ok(())) => Fallback::Held,
            _ => {
                let stop_until = until.min(self.half_deadline_from_now());
                let stop = self.stopping(&world, stop_until, &mut answer);
                stop.map_or(Fallback::Nothing, |c| Fallback::Stop(Box::new(c)))
            }
        };
        if let Some(h) = warm_from {
            let (plan, origin) = (h.plan.clone(), h.origin_ns);
            let warm_until = until.min(self.half_deadline_from_now());
            match self.refine(&plan, seconds(origin, origin_ns), start, warm_until, &mut answer) {
                Ok(Some(candidate)) => {
                    answer.warm = true;
                    return self.adopt(candidate, answer);
                }
                Ok(None) => why = Why::NotVerified,
                Err(w) => why = w,
            }
        }
        // A held plan to these goals that may still be followed serves: no
        // cold plan runs for them and the answer does not wait for one (a
        // late one would make the robots jump by what two plans differ
        // over its latency).
        if to_goals && matches!(checked, Some(Ok(()))) {
            if self.pending.take().is_some() {
                self.cold.cancel();
            }
            self.fresh = None;
            return self.fall_back(Fallback::Held, why, answer);
        }
        // A verified cold plan the robots had left: repaired from here.
        if let Some(fresh) = self.fresh.take().filter(|f| same_goals(&f.problem.goals, &world.problem)) {
            let dt = seconds(fresh.origin_ns, origin_ns);
            if let Ok(Some(candidate)) = self.refine(&fresh.plan, dt, &world, until, &mut answer) {
                return self.adopt(candidate, answer);
            }
        }
        // Cold: keep a request for these goals and obstacles running, or start one.
        let running = self
            .pending
            .as_ref()
            .is_some_and(|p| same_goals(&p.goals, &world.problem) && p.obstacles == world.problem.obstacles.len());
        if !running {
            // The snapshot's sequence seeds the learned planner's noise.
            let id = self.cold.submit(&start.problem, sequence, origin_ns, sequence);
            self.pending = Some(Pending {
                id,
                goals: world.problem.goals.clone(),
                obstacles: world.problem.obstacles.len(),
                outstanding: self.cold.members(),
            });
        }
        // Wait for the cold plan until the answer is due.
        while self.pending.is_some() {
            let Some(result) = self.cold.wait_until(until) else { break };
            if let Some(adopted) = self.take_cold(result, &mut answer, until) {
                return adopted;
            }
        }
        if self.pending.is_none() && why == Why::DeadlineMissed {
            // A verified cold plan refused over the limits says so.
            why = if answer.why == Why::Limits { Why::Limits } else { Why::NotVerified };
        }
        let why = match checked {
            Some(Err(w)) => w,
            _ => why,
        };
        self.fall_back(fallback, why, answer)
    }

    /// Answers a snapshot whose measurement was accepted but whose task
    /// (its goals, from where the robots are) cannot be planned: its world
    /// becomes the newest, and the answer is the held plan if it may still
    /// be followed in it, else a stopping plan verified against it, else
    /// nothing. The caller reports the task's rejection as the reason.
    pub fn observe(&mut self, problem: Problem, origin_ns: u64, sequence: u64, deadline: Instant) -> Answer {
        let world = World { problem, origin_ns, sequence };
        self.newest = Some(world.clone());
        let mut answer = Answer::new(Follow::Nothing, Why::None);
        let fallback = match self.held.as_ref().map(|h| self.followable(h, &world)) {
            Some(Ok(())) => Fallback::Held,
            checked => {
                if let Some(Err(w)) = checked {
                    answer.why = w;
                }
                let until = self.until(deadline);
                self.stopping(&world, until, &mut answer).map_or(Fallback::Nothing, |c| Fallback::Stop(Box::new(c)))
            }
        };
        let why = answer.why;
        self.fall_back(fallback, why, answer)
    }

    /// What to follow after a snapshot that is not a measurement (rejected
    /// before its task), or after silence, at `now_ns`: the held plan while
    /// the newest accepted snapshot is at most `stale_after_ms` old (it was
    /// checked against that world when it was last published), else nothing.
    pub fn reissue(&mut self, now_ns: u64) -> Follow {
        let fresh =
            self.newest.as_ref().is_some_and(|w| now_ns.saturating_sub(w.origin_ns) <= self.rules.stale_after_ns);
        if self.held.is_some() && fresh {
            Follow::Held
        } else {
            self.held = None;
            Follow::Nothing
        }
    }

    /// A cold result that arrived outside any snapshot's deadline: adopted
    /// if it verified and may be followed in the newest world (or can be
    /// repaired from there at once), returned as the answer to publish.
    pub(crate) fn on_cold(&mut self, result: RaceResult) -> Option<Answer> {
        let mut answer = Answer::new(Follow::Nothing, Why::None);
        let until = self.half_deadline_from_now();
        self.take_cold(result, &mut answer, until)
    }

    /// Takes one cold result: the answer if its plan was adopted.
    fn take_cold(&mut self, result: RaceResult, answer: &mut Answer, until: Instant) -> Option<Answer> {
        let verified = result.outcome.as_ref().is_ok_and(Planned::verified);
        let stop = result.outcome.as_ref().map(|p| p.stop);
        debug!(by = result.by, verified, ?stop, "cold result");
        let pending = self.pending.as_mut().filter(|p| p.id == result.request.id)?;
        pending.outstanding = pending.outstanding.saturating_sub(1);
        let last = pending.outstanding == 0;
        let planned = result.outcome.ok();
        if let Some(p) = &planned {
            answer.iterations += p.iterations;
            answer.stages.add(&p.stages);
        }
        let request = result.request;
        // The first verified plan within the limits wins the race; one over
        // them leaves the others running.
        let Some((planned, plan)) = planned.filter(Planned::verified).and_then(|p| {
            let plan = self.within_limits(p.plan.clone(), &request.problem);
            if plan.is_err() {
                answer.why = Why::Limits;
            }
            Some(p).zip(plan.ok())
        }) else {
            if last {
                self.pending = None;
            }
            return None;
        };
        self.cold.cancel();
        self.pending = None;
        answer.candidates = planned.candidates;
        let won = |answer: &Answer| Answer { by: Some(planned.by), ..answer.clone() };
        let candidate = Candidate {
            plan,
            problem: request.problem,
            origin_ns: request.origin_ns,
            sequence: request.sequence,
            primal: planned.primal,
        };
        let world = self.newest.clone()?;
        if !same_goals(&candidate.problem.goals, &world.problem) {
            return None;
        }
        let followable = self.may_follow(&candidate.plan, candidate.origin_ns, Kind::Goals, &world);
        if followable.is_ok() {
            return Some(self.adopt(candidate, won(answer)));
        }
        let dt = seconds(candidate.origin_ns, world.origin_ns);
        match self.refine(&candidate.plan, dt, &world, until, answer) {
            Ok(Some(repaired)) => Some(self.adopt(repaired, won(answer))),
            repair => {
                // Within the limits, so the answer's reason is no longer theirs.
                answer.why = Why::NotVerified;
                let deviation = candidate.plan.deviation(dt, &world.problem.starts);
                debug!(?followable, dt, deviation, repaired = ?repair.map(|c| c.is_some()), "a verified cold plan not followable, not repaired");
                self.fresh = Some(candidate);
                None
            }
        }
    }

    /// Makes `candidate` the held plan (to the goals) and answers with it.
    fn adopt(&mut self, candidate: Candidate, mut answer: Answer) -> Answer {
        self.cold.cancel();
        self.pending = None;
        self.fresh = None;
        self.held = Some(Held::of(candidate, Kind::Goals, self.team.samples));
        answer.follow = Follow::New;
        answer.why = Why::None;
        answer
    }

    /// Publishes `fallback` for `why`: the held plan, the stopping plan
    /// (now the held one), or nothing (nothing held).
    fn fall_back(&mut self, fallback: Fallback, why: Why, mut answer: Answer) -> Answer {
        answer.why = why;
        answer.follow = match fallback {
            Fallback::Held => Follow::Held,
            Fallback::Stop(candidate) => {
                self.held = Some(Held::of(*candidate, Kind::Stopping, self.team.samples));
                Follow::Stopping
            }
            Fallback::Nothing => {
                self.held = None;
                Follow::Nothing
            }
        };
        answer
    }
}

#[cfg(test)]
mod tests;
