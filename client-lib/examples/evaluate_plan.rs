//! Evaluates a plan message given as its raw bytes (a `JointTrajectory` of
//! `docs/MESSAGES.md`, 98504 bytes) at given times and prints JSON: the
//! message's header fields and, when its status carries a plan, every
//! robot's position, velocity and acceleration at each time (seconds after
//! `plan_origin_ns`) from `JointTrajectory::sample`. The Python and C++
//! clients' tests compare their own evaluation with it:
//!
//! ```text
//! cargo run --release -p flowopt-client --example evaluate_plan -- plan.bin 0 1.25 5
//! cat plan.bin | target/release/examples/evaluate_plan - 0 1.25 5
//! ```

use std::fmt::Write as _;
use std::io::Read;
use std::mem::size_of;

use flowopt_client::JointTrajectory;

fn main() {
    if let Err(error) = run() {
        eprintln!("evaluate_plan: {error}");
        std::process::exit(2);
    }
}

fn run() -> Result<(), String> {
    let mut args = std::env::args().skip(1);
    let usage = "usage: evaluate_plan <plan.bin | -> [t_seconds ...]";
    let path = args.next().ok_or(usage)?;
    let times: Vec<f64> = args
        .map(|a| a.parse::<f64>().map_err(|_| format!("not a time in seconds: {a:?}; {usage}")))
        .collect::<Result<_, _>>()?;
    let bytes = if path == "-" {
        let mut bytes = Vec::new();
        std::io::stdin().read_to_end(&mut bytes).map_err(|e| format!("reading stdin: {e}"))?;
        bytes
    } else {
        std::fs::read(&path).map_err(|e| format!("reading {path}: {e}"))?
    };
    let msg = from_bytes(&bytes)?;
    println!("{}", to_json(&msg, &times));
    Ok(())
}

/// The message whose raw bytes are `bytes`.
fn from_bytes(bytes: &[u8]) -> Result<Box<JointTrajectory>, String> {
    let size = size_of::<JointTrajectory>();
    if bytes.len() != size {
        return Err(format!("a JointTrajectory is {size} bytes, got {}", bytes.len()));
    }
    let mut msg = Box::new(JointTrajectory::new());
    // SAFETY: every field of a `JointTrajectory` is an integer, a float or an
    // array of them, so every byte pattern is a valid value (messages.rs);
    // `bytes` holds exactly `size` bytes and does not overlap the box.
    unsafe {
        std::ptr::copy_nonoverlapping(bytes.as_ptr(), (&mut *msg as *mut JointTrajectory).cast::<u8>(), size);
    }
    Ok(msg)
}

/// A JSON number (`null` for NaN and infinities, which JSON lacks).
fn num(x: f64) -> String {
    if x.is_finite() { format!("{x:?}") } else { "null".to_string() }
}

/// A JSON string.
fn text(s: &str) -> String {
    let mut out = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// `[[x, y(, z)], ...]`: one vector per robot, its first `axes` entries.
fn vectors(values: impl Iterator<Item = [f64; 3]>, axes: usize) -> String {
    let rows: Vec<String> =
        values.map(|v| format!("[{}]", v[..axes].iter().map(|&x| num(x)).collect::<Vec<_>>().join(","))).collect();
    format!("[{}]", rows.join(","))
}

/// The message's header fields and its kinematics at `times`, as JSON.
fn to_json(msg: &JointTrajectory, times: &[f64]) -> String {
    let mut out = String::from("{");
    let fields: [(&str, String); 22] = [
        ("version", msg.version.to_string()),
        ("status", msg.status.to_string()),
        ("reason", msg.reason.to_string()),
        ("reason_index", msg.reason_index.to_string()),
        ("team", msg.team_name().map_or("null".to_string(), text)),
        ("dim", msg.dim.to_string()),
        ("robots", msg.robots.to_string()),
        ("degree", msg.degree.to_string()),
        ("iterations", msg.iterations.to_string()),
        ("answers_sequence", msg.answers_sequence.to_string()),
        ("state_timestamp_ns", msg.state_timestamp_ns.to_string()),
        ("plan_sequence", msg.plan_sequence.to_string()),
        ("plan_origin_ns", msg.plan_origin_ns.to_string()),
        ("received_ns", msg.received_ns.to_string()),
        ("published_ns", msg.published_ns.to_string()),
        ("horizon", num(msg.horizon)),
        ("primal_residual", num(msg.primal_residual)),
        ("smoothness", num(msg.smoothness)),
        ("max_speed", num(msg.max_speed)),
        ("max_acceleration", num(msg.max_acceleration)),
        ("warm_started", msg.warm_started.to_string()),
        ("candidates", msg.candidates.to_string()),
    ];
    for (name, value) in fields {
        let _ = write!(out, "\"{name}\":{value},");
    }
    let _ = write!(out, "\"total_us\":{},", msg.timings.total_us);
    let axes = msg.dim.clamp(2, 3) as usize;
    let mut samples = Vec::new();
    for &t in times {
        match msg.sample(t) {
            Ok(kinematics) => samples.push(format!(
                "{{\"t\":{},\"position\":{},\"velocity\":{},\"acceleration\":{}}}",
                num(t),
                vectors(kinematics.iter().map(|k| k.position.into()), axes),
                vectors(kinematics.iter().map(|k| k.velocity.into()), axes),
                vectors(kinematics.iter().map(|k| k.acceleration.into()), axes),
            )),
            Err(error) => {
                let _ = write!(out, "\"error\":{},", text(&error.to_string()));
                break;
            }
        }
    }
    let _ = write!(out, "\"samples\":[{}]}}", samples.join(","));
    out
}
