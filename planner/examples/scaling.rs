//! The optimiser's threads against its time: crowds solved on each thread
//! count in turn (which count goes first rotates from problem to problem,
//! so that a noisy machine's slow seconds spread over all of them), each
//! `--repeats` times, its fastest kept; every plan checked bit for bit
//! against the first count's.
//!
//! ```text
//! cargo run --release -p flowopt-planner --example scaling -- \
//!     --robots 64,128,256 --threads 1,2 --problems 10 --repeats 3 --seed 11 --dim 2
//! ```
//!
//! Prints one markdown row per team size and thread count: the median
//! (over the problems) of the fastest time, the median of each problem's time on the first count over its
//! time on this one (the speed-up), how many plans verified, and whether
//! every plan equals the first count's.

use std::time::Instant;

use flowopt_planner::am::{AmSettings, Engine, Objective, Stop};
use flowopt_planner::problem::Dim;
use flowopt_planner::scenes::{Family, Scene};

fn main() {
    let mut robots = vec![64, 128, 256];
    let mut threads = vec![1, 2];
    let (mut problems, mut repeats, mut seed, mut dim) = (10u64, 3usize, 11u64, Dim::Two);
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        let value = args.next().unwrap_or_default();
        let list = |v: &str| -> Vec<usize> { v.split(',').filter_map(|x| x.trim().parse().ok()).collect() };
        match flag.as_str() {
            "--robots" => robots = list(&value),
            "--threads" => threads = list(&value),
            "--problems" => problems = value.parse().unwrap_or(problems),
            "--repeats" => repeats = value.parse().unwrap_or(repeats).max(1),
            "--seed" => seed = value.parse().unwrap_or(seed),
            "--dim" => dim = if value == "3" { Dim::Three } else { Dim::Two },
            _ => {
                eprintln!(
                    "unknown option {flag}; options: --robots LIST --threads LIST --problems N --repeats N --seed N --dim 2|3"
                );
                std::process::exit(2);
            }
        }
    }
    if robots.is_empty() || threads.is_empty() {
        eprintln!("--robots and --threads need at least one number each");
        std::process::exit(2);
    }
    println!("| robots | threads | median (ms) | speed-up over {} thread(s) | verified | same plans |", threads[0]);
    println!("| ---: | ---: | ---: | ---: | ---: | --- |");
    for &n in &robots {
        let mut times = vec![Vec::new(); threads.len()];
        let mut verified = vec![0; threads.len()];
        let mut same = vec![true; threads.len()];
        let mut engine: Option<Vec<Engine>> = None;
        for (p, s) in (seed..seed + problems).enumerate() {
            let problem = match Scene::new(Family::Crowd, dim, n, s).generate() {
                Ok((problem, _)) => problem,
                Err(e) => {
                    eprintln!("crowd of {n}, seed {s}: {e}");
                    std::process::exit(1);
                }
            };
            let engines = engine.get_or_insert_with(|| {
                threads
                    .iter()
                    .map(|&t| {
                        let settings = AmSettings { threads: t, ..AmSettings::optimiser() };
                        Engine::new(&problem.team, problem.obstacles.len(), Objective::smoothness(), settings)
                            .expect("the crowd's engine builds")
                    })
                    .collect()
            });
            let mut plans = vec![Vec::new(); threads.len()];
            let mut fastest = vec![f64::INFINITY; threads.len()];
            for r in 0..threads.len() * repeats {
                let t = (p + r) % threads.len();
                let started = Instant::now();
                let outcome = engines[t].solve(&problem).expect("a generated crowd is valid");
                fastest[t] = fastest[t].min(started.elapsed().as_secs_f64() * 1e3);
                if r < threads.len() {
                    verified[t] += usize::from(outcome.stop == Stop::Verified);
                    plans[t] = outcome.state.xi;
                }
            }
            for (t, time) in fastest.into_iter().enumerate() {
                times[t].push(time);
            }
            for t in 1..threads.len() {
                same[t] &= plans[t] == plans[0];
            }
        }
        for (t, &count) in threads.iter().enumerate() {
            let ratios: Vec<f64> = times[0].iter().zip(&times[t]).map(|(a, b)| a / b).collect();
            println!(
                "| {n} | {count} | {:.1} | {:.2}x | {}/{problems} | {} |",
                median(&times[t]),
                median(&ratios),
                verified[t],
                if same[t] { "yes" } else { "NO" }
            );
        }
    }
}

/// The median of `values` (the mean of the middle two for an even count).
fn median(values: &[f64]) -> f64 {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let m = v.len() / 2;
    if v.is_empty() {
        f64::NAN
    } else if v.len() % 2 == 1 {
        v[m]
    } else {
        0.5 * (v[m - 1] + v[m])
    }
}
