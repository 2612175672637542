//! How far a robot moving towards a side must go at the least, and which
//! robots that takes past the box ([`Problem::least_excursion`],
//! [`Problem::braking_excesses`]): the module's bounds applied to a
//! problem's starts.

use super::{AxisStart, GOAL_CHECK_NEAR, least_excursion, past_side_with_goal};
use crate::problem::{BrakingExcess, Problem};

impl Problem {
    /// How far robot `i`, from its start, must go at the least towards the
    /// `upper` (or lower) side on `axis` under any plan within
    /// `max_acceleration` ([`crate::braking`]; 0 moving away from it): the
    /// table's bound, and, where that leaves less than
    /// [`GOAL_CHECK_NEAR`] of room to the side, the tighter one with the
    /// robot's goal ([`past_side_with_goal`]; not in the daemon).
    pub fn least_excursion(&self, i: usize, axis: usize, upper: bool, max_acceleration: f64) -> f64 {
        let (t, s) = (&self.team, &self.starts[i]);
        let sign = if upper { 1.0 } else { -1.0 };
        let (speed, towards) = (sign * s.velocity[axis], sign * s.acceleration[axis]);
        let table = least_excursion(t.degree, t.samples, t.horizon, max_acceleration, towards, speed);
        let (side, room) = self.side_and_room(i, axis, upper);
        if speed <= 0.0 || table - room <= -GOAL_CHECK_NEAR {
            return table;
        }
        let start = AxisStart { motion: self.axis_motion(i, axis), side, upper };
        past_side_with_goal(self.team.form(max_acceleration), start).map_or(table, |past| table.max(room + past))
    }

    /// With [`crate::problem::Team::max_acceleration`], each robot and axis along which the
    /// robot, within [`crate::problem::FEASIBILITY_TOLERANCE`] of the box on that axis,
    /// moves towards a side it cannot stop before, or stops less than
    /// [`GOAL_CHECK_NEAR`] inside: how far past the side its least
    /// excursion takes it ([`Self::least_excursion`]; negative, the room
    /// it leaves). Beyond the tolerance that is a start violation
    /// ([`crate::problem::Against::Braking`]); within it, a floor the plan
    /// keeps to ([`crate::recovery`]), at the side where it can stop inside.
    pub fn braking_excesses(&self) -> impl Iterator<Item = BrakingExcess> + '_ {
        let team = &self.team;
        let slack = team.box_tolerance();
        let axes = team.dim.axes();
        team.max_acceleration.into_iter().flat_map(move |max_acceleration| {
            (0..self.starts.len() * axes).filter_map(move |k| {
                let (robot, axis) = (k / axes, k % axes);
                let (p, v) = (self.starts[robot].position[axis], self.starts[robot].velocity[axis]);
                let (lo, hi) = (team.workspace.min[axis], team.workspace.max[axis]);
                // Outside on this axis it is `Against::Box`.
                if v == 0.0 || p < lo - slack || p > hi + slack {
                    return None;
                }
                let upper = v > 0.0;
                let (_, room) = self.side_and_room(robot, axis, upper);
                let least = self.least_excursion(robot, axis, upper, max_acceleration);
                let excess = least - room;
                (excess > -GOAL_CHECK_NEAR).then_some(BrakingExcess {
                    robot,
                    axis,
                    upper,
                    least,
                    excess,
                    tolerated: excess <= slack,
                })
            })
        })
    }

    /// The `upper` (or lower) side of the box on `axis`, and how far robot
    /// `i`'s start is from it (m; negative outside).
    fn side_and_room(&self, i: usize, axis: usize, upper: bool) -> (f64, f64) {
        let (w, p) = (&self.team.workspace, self.starts[i].position[axis]);
        if upper { (w.max[axis], w.max[axis] - p) } else { (w.min[axis], p - w.min[axis]) }
    }
}
