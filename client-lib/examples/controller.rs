//! A minimal controller: publishes the state of a 16-robot team (the
//! default configuration's) at 50 Hz for two seconds and prints where the
//! newest plan wants robot 0. Start the daemon first:
//!
//! ```text
//! cargo run --release -- serve &
//! cargo run --release -p flowopt-client --example controller
//! ```

use std::time::{Duration, Instant};

use flowopt_client::clock::monotonic_ns;
use flowopt_client::{ClientError, Endpoint, TeamChannel};

fn main() -> Result<(), ClientError> {
    let endpoint = Endpoint::new("example-controller")?;
    let channel = TeamChannel::new("flowopt", "default")?;
    let mut states = endpoint.state_publisher(&channel)?;
    let plans = endpoint.plan_subscriber(&channel)?;
    // Robots on a 4 x 4 grid, each going to the mirrored cell.
    let cell = |k: usize| [-0.75 + 0.5 * (k % 4) as f64, -0.75 + 0.5 * (k / 4) as f64, 0.0];
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(2) {
        let sequence = states.publish_with(|s| {
            s.dim = 2;
            s.robots = 16;
            for (k, r) in s.robot.iter_mut().take(16).enumerate() {
                r.position = cell(k);
                r.goal = cell(15 - k);
            }
        })?;
        match plans.wait(Duration::from_millis(20))? {
            Some(plan) if plan.status.has_plan() => {
                let t = plan.elapsed_s(monotonic_ns());
                let robot0 = plan.sample_robot(0, t + 1.0)?;
                println!(
                    "snapshot {sequence}: plan for {} ({:?}, {} us), robot 0 in 1 s at {:.3?}",
                    plan.answers_sequence, plan.status, plan.timings.total_us, robot0.position
                );
            }
            Some(reply) => println!("snapshot {sequence}: {:?} ({:?})", reply.status, reply.reason),
            None => println!("snapshot {sequence}: no plan yet (is `flowopt serve` running?)"),
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}
