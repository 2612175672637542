//! The certificates' linear programs against their time: per team shape
//! (degree, samples; 5 s, 3 m/s^2), the braking table, the bound with the
//! goal per start and a robot's reach per instant; then the validation of
//! the cold starts from motion of docs/BENCHMARKS.md (16 robots at 0.3,
//! 0.6 and 1.0 m/s, seeds 900, 2000 and 3000, 50 each), certified or not.
//!
//! ```text
//! cargo run --release -p flowopt-planner --example programs
//! ```
//!
//! With `VALUES=path`, each shape's program values are written to
//! `path-DEGREE`, one per line (to compare two builds bit for bit).

use std::time::Instant;

use flowopt_planner::braking::{AxisMotion, AxisStart, Form, Reach, least_past_side};
use flowopt_planner::problem::Dim;
use flowopt_planner::scenes::{Family, Scene};

fn main() {
    println!("| degree / samples | table (ms) | bound with the goal (us each) | reach (us per instant) |");
    println!("| --- | ---: | ---: | ---: |");
    for (degree, samples) in [(10, 50), (16, 78), (20, 100)] {
        let form = Form { degree, samples, horizon: 5.0, max_acceleration: 3.0 };
        let mut values = Vec::new();
        let started = Instant::now();
        flowopt_planner::braking::prepare(degree, samples, form.horizon, form.max_acceleration);
        let table = started.elapsed().as_secs_f64() * 1e3;
        let started = Instant::now();
        for k in 0..50 {
            let k = k as f64;
            let motion = AxisMotion {
                position: 0.5 + 0.01 * k,
                velocity: 0.3 + 0.02 * k,
                acceleration: 0.0,
                goal: -0.5 + 0.013 * k,
            };
            values.push(least_past_side(form, AxisStart { motion, side: 1.0, upper: true }).unwrap_or(f64::NAN));
        }
        let to_goal = started.elapsed().as_secs_f64() * 1e6 / 50.0;
        let started = Instant::now();
        for k in 0..20 {
            let k = k as f64;
            let motion = AxisMotion { position: 0.1 * k - 1.0, velocity: 1.0 - 0.1 * k, acceleration: 0.0, goal: 0.3 };
            let Some(mut reach) = Reach::new(form, motion) else { continue };
            for s in 1..10 {
                let (lo, hi) = reach.at(0.02 * s as f64).unwrap_or((f64::NAN, f64::NAN));
                values.extend([lo, hi]);
            }
        }
        let reach = started.elapsed().as_secs_f64() * 1e6 / 180.0;
        println!("| {degree} / {samples} | {table:.1} | {to_goal:.1} | {reach:.1} |");
        if let Ok(path) = std::env::var("VALUES") {
            let text: String = values.iter().map(|v| format!("{v:.12}\n")).collect();
            if let Err(e) = std::fs::write(format!("{path}-{degree}"), text) {
                eprintln!("writing {path}-{degree}: {e}");
            }
        }
    }
    let (mut certified, mut uncertified) = (Vec::new(), Vec::new());
    for seed0 in [900u64, 2000, 3000] {
        for speed in [0.3, 0.6, 1.0] {
            for seed in seed0..seed0 + 50 {
                let scene = Scene { start_speed: speed, ..Scene::new(Family::Random, Dim::Two, 16, seed) };
                let Ok((mut problem, _)) = scene.generate() else { continue };
                problem.team.max_acceleration = Some(3.0);
                let started = Instant::now();
                let verdict = problem.validate();
                let ms = started.elapsed().as_secs_f64() * 1e3;
                if verdict.is_ok() { uncertified.push(ms) } else { certified.push(ms) }
            }
        }
    }
    for v in [&mut certified, &mut uncertified] {
        v.sort_by(f64::total_cmp);
    }
    let at = |v: &[f64], q: f64| v.get(((v.len() as f64 - 1.0) * q).round() as usize).copied().unwrap_or(f64::NAN);
    println!(
        "\nvalidation of 450 starts from motion: {} certified (median {:.3} ms, max {:.3}), {} not (median {:.3} ms, max {:.3})",
        certified.len(),
        at(&certified, 0.5),
        at(&certified, 1.0),
        uncertified.len(),
        at(&uncertified, 0.5),
        at(&uncertified, 1.0)
    );
}
