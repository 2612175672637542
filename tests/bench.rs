//! `flowopt bench`'s report, end to end: the command a row of
//! docs/BENCHMARKS.md names, on a few small instances.

use std::process::Command;

/// `flowopt bench --json` of three 4-robot random instances from rest by
/// the optimiser, with `extra` arguments: its summary.
fn bench(extra: &[&str]) -> serde_json::Value {
    let out = Command::new(env!("CARGO_BIN_EXE_flowopt"))
        .args(["bench", "--method", "baseline", "--robots", "4", "--problems", "3", "--json", "--no-study"])
        .args(extra)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

#[test]
fn over_acceleration_counts_the_successful_plans_over_the_limit_and_only_with_one() {
    // From rest nothing is certified infeasible, whatever the limit.
    let without = bench(&[]);
    assert_eq!(without["success_rate"], 1.0);
    assert!(without["over_acceleration"].is_null(), "{without}");
    // Every plan accelerates: each is over a limit of 1 mm/s^2 ...
    let tiny = bench(&["--max-acceleration", "0.001"]);
    assert_eq!((tiny["certified_infeasible"].as_u64(), tiny["success_rate"].as_f64()), (Some(0), Some(1.0)));
    assert_eq!(tiny["over_acceleration"], 3, "{tiny}");
    // ... and none over 1 km/s^2.
    let huge = bench(&["--max-acceleration", "1000"]);
    assert_eq!(huge["over_acceleration"], 0, "{huge}");
}
