//! A minimal controller that obeys the followability contract: it flies a
//! 16-robot team (the default configuration's) at 50 Hz for four seconds,
//! each robot going to the mirrored cell of a 4 x 4 grid. Its robots track
//! the trajectory to follow exactly (an ideal controller) and stay where
//! they are while there is none. Start the daemon first:
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
    let mut plans = endpoint.plan_subscriber(&channel, &states)?;
    let cell = |k: usize| [-0.75 + 0.5 * (k % 4) as f64, -0.75 + 0.5 * (k / 4) as f64, 0.0];
    let mut position: Vec<[f64; 3]> = (0..16).map(cell).collect();
    let mut velocity = vec![[0.0; 3]; 16];
    let started = Instant::now();
    while started.elapsed() < Duration::from_secs(4) {
        let now = monotonic_ns();
        // Track what the contract says to follow; without it, hold still.
        match plans.to_follow() {
            Some(followed) => {
                for (i, k) in followed.at(now).iter().enumerate() {
                    position[i] = k.position.into();
                    velocity[i] = k.velocity.into();
                }
            }
            None => velocity.iter_mut().for_each(|v| *v = [0.0; 3]),
        }
        let sequence = states.publish_with(|s| {
            s.timestamp_ns = now;
            s.dim = 2;
            s.robots = 16;
            for (k, r) in s.robot.iter_mut().take(16).enumerate() {
                r.position = position[k];
                r.velocity = velocity[k];
                r.goal = cell(15 - k);
            }
        })?;
        match plans.wait(Duration::from_millis(20))? {
            Some(msg) => println!(
                "snapshot {sequence}: answer to {} is {:?} ({:?}, {} us); following the plan of snapshot {:?}",
                msg.answers_sequence,
                msg.status(),
                msg.reason(),
                msg.timings.total_us,
                plans.to_follow().map(|f| f.plan_sequence)
            ),
            None => println!("snapshot {sequence}: no answer yet (is `flowopt serve` running?)"),
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    Ok(())
}
