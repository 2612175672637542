//! The projection step: positions at a grid of instants, and the push
//! `e - F xi` that moves every violating robot to the constraint surface.
//!
//! With `d` the offset between two robots (or a robot and an obstacle) and
//! `r = ||diag(a, a, b)^-1 d||` its scaled length, the projected offset is
//! `e = d max(1, 1/r)`: non-violating rows are left alone, violating ones are
//! pushed radially onto the spheroid (the normalised difference, no angles).
//! The box clamps positions. Corrections are summed per robot (`+c` to `i`,
//! `-c` to `j` for a pair row) in position space, and their squared norms give
//! the primal residual `||F xi - e|| + ||G xi - h + s||`.
//!
//! The same code checks feasibility: on the dense grid with the true sizes
//! shrunk by the tolerance, a plan is feasible exactly when no correction is
//! needed.
//!
//! One operation per file: [`grid`] (the instants and the basis there),
//! [`limits`] (sizes, box and obstacle tracks), [`check`] (the screen and
//! the push of one pair or obstacle), [`correct`] (every pair, obstacle and
//! the box, per robot block on a crew), [`memory`] (the working memory).

mod check;
mod correct;
mod grid;
mod limits;
mod memory;
mod run;

pub(crate) use grid::SampleGrid;
pub use limits::Limits;
pub(crate) use memory::Projection;
pub(crate) use memory::{ROBOT_BLOCK, block_robots};

#[cfg(test)]
mod tests {
    use super::*;
    use crate::crew::Crew;
    use crate::problem::{Dim, Problem};
    use crate::problem::{Obstacle, Spheroid, StartState, Team};
    use nalgebra::Vector3;

    /// Two robots held at fixed points (constant coefficients) on a 1-instant
    /// grid in the middle of the horizon.
    fn setup(p0: [f64; 2], p1: [f64; 2], obstacles: Vec<Obstacle>) -> (Problem, SampleGrid, Vec<f64>) {
        let team = Team::default_for(Dim::Two, 2);
        let nx = team.degree + 1;
        let mut xi = vec![0.0; 2 * 2 * nx];
        for (i, p) in [p0, p1].iter().enumerate() {
            for a in 0..2 {
                xi[(a * 2 + i) * nx..(a * 2 + i + 1) * nx].fill(p[a]);
            }
        }
        let problem = Problem {
            team: team.clone(),
            starts: vec![
                StartState::at_rest(Vector3::new(p0[0], p0[1], 0.0)),
                StartState::at_rest(Vector3::new(p1[0], p1[1], 0.0)),
            ],
            goals: vec![Vector3::new(p0[0], p0[1], 0.0), Vector3::new(p1[0], p1[1], 0.0)],
            obstacles,
        };
        (problem, SampleGrid::new(team.degree, vec![0.5]), xi)
    }

    fn corr(p: &Projection, axis: usize, robot: usize) -> f64 {
        p.corr[axis * 2 + robot]
    }

    #[test]
    fn a_violating_pair_is_pushed_apart_to_the_surface_symmetrically() {
        // 0.1 m apart along x, separation 0.2: each gets half of the 0.1 m gap.
        let (problem, grid, xi) = setup([0.0, 0.0], [0.1, 0.0], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(&Crew::alone(), Dim::Two, 2, &grid, &limits, &xi);
        // The pair row's target is d / r = (-0.2, 0): the correction is -0.1 on
        // robot 0 and +0.1 on robot 1; the residual is the 0.1 m deficit.
        assert!((corr(&p, 0, 0) + 0.1).abs() < 1e-12 && (corr(&p, 0, 1) - 0.1).abs() < 1e-12);
        assert_eq!((corr(&p, 1, 0), corr(&p, 1, 1)), (0.0, 0.0));
        assert!((primal - 0.1).abs() < 1e-12);
        assert_eq!(p.touched, vec![true, true]);
    }

    #[test]
    fn pairs_outside_the_separation_are_left_alone() {
        let (problem, grid, xi) = setup([0.0, 0.0], [0.15, 0.15], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        assert_eq!(p.run(&Crew::alone(), Dim::Two, 2, &grid, &limits, &xi), 0.0);
        assert!(p.corr.iter().all(|&c| c == 0.0) && p.touched == vec![false, false]);
        // Inflating by 10% makes the same pair (0.212 m apart) violate.
        let inflated = Limits::new(&problem, &grid, 1.1, [0.0; 3]);
        assert!(p.run(&Crew::alone(), Dim::Two, 2, &grid, &inflated, &xi) > 0.0);
    }

    #[test]
    fn coincident_robots_are_parted_along_a_unit_direction() {
        let (problem, grid, xi) = setup([0.3, 0.3], [0.3, 0.3], vec![]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(&Crew::alone(), Dim::Two, 2, &grid, &limits, &xi);
        let (cx, cy) = (corr(&p, 0, 0), corr(&p, 1, 0));
        assert!(((cx * cx + cy * cy).sqrt() - 0.2).abs() < 1e-12);
        assert!((primal - 0.2).abs() < 1e-12);
    }

    #[test]
    fn a_robot_inside_an_obstacle_is_pushed_out_radially_and_the_box_clamps() {
        let obstacle =
            Obstacle { position: Vector3::new(0.0, 0.0, 0.0), velocity: Vector3::zeros(), shape: Spheroid::ball(0.1) };
        // Robot 0 at (0.1, 0) inside the 0.2 m inflated obstacle; robot 1 at
        // x = 1.05, outside the [-1, 1] box.
        let (problem, grid, xi) = setup([0.1, 0.0], [1.05, 0.5], vec![obstacle]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(&Crew::alone(), Dim::Two, 2, &grid, &limits, &xi);
        assert!((corr(&p, 0, 0) - 0.1).abs() < 1e-12, "pushed to x = 0.2");
        assert!((corr(&p, 0, 1) + 0.05).abs() < 1e-12, "clamped to x = 1");
        assert!((primal - (0.1 + 0.05)).abs() < 1e-12);
        // A box inset of 0.1 m clamps robot 1 to 0.9 instead.
        let inset = Limits::new(&problem, &grid, 1.0, [0.1; 3]);
        p.run(&Crew::alone(), Dim::Two, 2, &grid, &inset, &xi);
        assert!((corr(&p, 0, 1) + 0.15).abs() < 1e-12);
    }

    #[test]
    fn a_moving_obstacle_is_tracked_in_time() {
        // At tau = 0.5 (t = 2.5 s) an obstacle starting at x = -0.25 moving at
        // 0.1 m/s sits at x = 0: it overlaps a robot at the origin.
        let moving = Obstacle {
            position: Vector3::new(-0.25, 0.0, 0.0),
            velocity: Vector3::new(0.1, 0.0, 0.0),
            shape: Spheroid::ball(0.1),
        };
        let (problem, grid, xi) = setup([0.0, 0.05], [0.8, 0.8], vec![moving]);
        let limits = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        let primal = p.run(&Crew::alone(), Dim::Two, 2, &grid, &limits, &xi);
        assert!((corr(&p, 1, 0) - 0.15).abs() < 1e-12, "pushed from y = 0.05 to y = 0.2");
        assert!((primal - 0.15).abs() < 1e-12);
    }

    #[test]
    fn the_chord_inflation_pushes_fast_pairs_further_apart() {
        // Two robots 0.21 m apart (beyond the 0.2 m separation) at the
        // middle instant of three, passing each other at 1 m/s relative
        // over instants 0.1 s apart: the straight motion between instants
        // dips to 0.2 * ... below the separation, so the chord target asks
        // for more.
        let team = Team::default_for(Dim::Two, 2);
        let problem = setup([0.0, 0.0], [0.21, 0.0], vec![]).0;
        let grid = SampleGrid::new(team.degree, vec![0.45, 0.5, 0.55]);
        let nx = team.degree + 1;
        // Robot 0 still at the origin; robot 1 moving along y at 1 m/s
        // (T = 5 s, so 0.25 m between these instants), at x = 0.21.
        let mut xi = vec![0.0; 2 * 2 * nx];
        for c in 0..nx {
            let tau = c as f64 / (nx - 1) as f64;
            xi[nx + c] = 0.21;
            xi[3 * nx + c] = 5.0 * (tau - 0.5);
        }
        let plain = Limits::new(&problem, &grid, 1.0, [0.0; 3]);
        let mut p = Projection::new(Dim::Two, 2, &grid);
        assert_eq!(p.run(&Crew::alone(), Dim::Two, 2, &grid, &plain, &xi), 0.0, "clear at every instant");
        let chord = plain.clone().with_rules(true, false);
        let primal = p.run(&Crew::alone(), Dim::Two, 2, &grid, &chord, &xi);
        assert!(primal > 0.0, "the chords between the instants dip through the separation");
        // The middle instant is pushed to sqrt(1 + L^2/4) separations, L =
        // 0.25 / 0.2 the scaled move: 0.2 * sqrt(1 + 1.25^2 / 4) = 0.2358 m.
        let target = 0.2 * (1.0f64 + 1.25 * 1.25 / 4.0).sqrt();
        assert!((corr(&p, 1, 1) - corr(&p, 0, 1) - (target - 0.21)).abs() < 1e-9);
    }

    /// `iterations` iterations of the optimiser with `settings` on
    /// `problem` from its cold start, every residual recorded.
    fn optimise(problem: &Problem, settings: crate::am::AmSettings, iterations: usize) -> crate::am::AmOutcome {
        use crate::am::{Engine, Objective};
        let mut settings = settings.residual_study(-1.0);
        settings.max_iterations = iterations;
        let engine = Engine::new(&problem.team, problem.obstacles.len(), Objective::smoothness(), settings).unwrap();
        let prepared = engine.prepare(problem, None).unwrap();
        engine.run(&prepared, engine.cold_start(&prepared))
    }

    #[test]
    fn every_crew_size_iterates_the_same_numbers() {
        use crate::am::AmSettings;
        use crate::problem::Obstacle;
        use crate::scenario::RandomScenario;
        // Kept broad-phase sets from 128 robots, all pairs below 24; one
        // thread per robot block at most.
        for (dim, robots, obstacles) in [(Dim::Two, 130, 2), (Dim::Two, 70, 3), (Dim::Three, 64, 2), (Dim::Two, 20, 0)]
        {
            let team = Team {
                workspace: crate::problem::Workspace::centred(crate::scenes::density_half_width(dim, robots)),
                ..Team::default_for(dim, robots)
            };
            let mut problem = RandomScenario::new(team.clone()).with_obstacles(obstacles).generate(3).unwrap();
            if let Some(o) = problem.obstacles.first_mut() {
                // A moving one too.
                *o = Obstacle { velocity: nalgebra::Vector3::new(0.2, -0.1, 0.0), ..*o };
            }
            let run = |threads| optimise(&problem, AmSettings { threads, ..AmSettings::optimiser() }, 60);
            let one = run(1);
            assert!(one.history.iter().any(|r| r.primal > 0.0), "the pairs are exercised");
            let bits = |h: &[crate::am::Residuals]| -> Vec<(u64, u64)> {
                h.iter().map(|r| (r.primal.to_bits(), r.fixed_point.to_bits())).collect()
            };
            for threads in [2, 3, 5] {
                let other = run(threads);
                assert_eq!(other.state, one.state, "{dim:?} {robots} robots, {threads} threads");
                assert_eq!(bits(&other.history), bits(&one.history), "{dim:?} {robots} robots, {threads} threads");
            }
        }
    }

    #[test]
    fn a_solve_with_its_verifications_and_restarts_is_the_same_on_every_crew() {
        use crate::am::{AmSettings, Engine, Objective};
        use crate::scenes::{Family, Scene};
        let (problem, _) = Scene { obstacles: 2, ..Scene::new(Family::Crowd, Dim::Two, 130, 5) }.generate().unwrap();
        let solve = |threads| {
            let settings = AmSettings { threads, ..AmSettings::optimiser() };
            let engine = Engine::new(&problem.team, 2, Objective::smoothness(), settings).unwrap();
            engine.solve(&problem).unwrap()
        };
        let one = solve(1);
        assert_eq!(one.stop, crate::am::Stop::Verified);
        for threads in [2, 4] {
            let other = solve(threads);
            assert_eq!((other.state, other.iterations, other.stop), (one.state.clone(), one.iterations, one.stop));
        }
    }

    #[test]
    fn stopping_at_the_first_violation_decides_as_the_whole_projection_does() {
        use crate::am::{AmSettings, Engine, Objective};
        use crate::scenario::RandomScenario;
        let team = Team { workspace: crate::problem::Workspace::centred(1.6), ..Team::default_for(Dim::Two, 40) };
        let problem = RandomScenario::new(team.clone()).with_obstacles(2).generate(1).unwrap();
        let engine = Engine::new(&team, 2, Objective::smoothness(), AmSettings::optimiser()).unwrap();
        let prepared = engine.prepare(&problem, None).unwrap();
        let solved = engine.solve_prepared(&prepared).state.xi;
        let mut verdicts = Vec::new();
        // Kept across the iterates: each call checks first the pair the
        // previous one stopped at.
        let mut kept = [Projection::new(Dim::Two, 40, &engine.grid), Projection::new(Dim::Two, 40, &engine.dense)];
        for xi in [
            optimise(&problem, AmSettings::optimiser(), 0).state.xi,
            optimise(&problem, AmSettings::optimiser(), 30).state.xi,
            solved,
        ] {
            for (g, (grid, limits)) in
                [(&engine.grid, &prepared.constraint), (&engine.dense, &prepared.verify)].into_iter().enumerate()
            {
                let clear = Projection::new(Dim::Two, 40, grid).clear(&Crew::alone(), Dim::Two, 40, grid, limits, &xi);
                let residual = Projection::new(Dim::Two, 40, grid).run(&Crew::alone(), Dim::Two, 40, grid, limits, &xi);
                assert_eq!(clear, residual == 0.0, "residual {residual}");
                assert_eq!(kept[g].clear(&Crew::alone(), Dim::Two, 40, grid, limits, &xi), clear);
                verdicts.push(clear);
            }
        }
        assert!(verdicts.contains(&true) && verdicts.contains(&false), "{verdicts:?}");
    }

    #[test]
    fn the_broad_phase_iteration_equals_the_all_pairs_one() {
        use crate::am::AmSettings;
        use crate::scenario::RandomScenario;
        let team = Team { workspace: crate::problem::Workspace::centred(1.6), ..Team::default_for(Dim::Two, 40) };
        for seed in 0..3 {
            let problem = RandomScenario::new(team.clone()).with_obstacles(2).generate(seed).unwrap();
            let run = |broad_phase| optimise(&problem, AmSettings { broad_phase, ..AmSettings::optimiser() }, 60);
            let (broad, all) = (run(true), run(false));
            assert!(all.history.iter().any(|r| r.primal > 0.0), "the pairs are exercised");
            assert_eq!(broad.state, all.state, "seed {seed}");
            let bits = |h: &[crate::am::Residuals]| -> Vec<(u64, u64)> {
                h.iter().map(|r| (r.primal.to_bits(), r.fixed_point.to_bits())).collect()
            };
            assert_eq!(bits(&broad.history), bits(&all.history), "seed {seed}");
        }
    }
}
