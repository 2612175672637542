//! The daemon's Prometheus metrics, per team: answers by status and
//! reason, the answer latency (a snapshot's arrival to its answer's
//! publication), answers past the deadline and the cold planners' wins;
//! served as OpenMetrics text on `GET /metrics` (`flowopt serve --metrics
//! ADDR`).
//!
//! Recording is an atomic add: a counter is created (allocating its
//! labels) the first time its status and reason occur, and kept.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use flowopt_client::{PlanStatus, Reason};
use prometheus_client::encoding::EncodeLabelSet;
use prometheus_client::encoding::text::encode;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::histogram::{Histogram, exponential_buckets};
use prometheus_client::registry::Registry;
use thiserror::Error;
use tracing::info;

use crate::http;

/// Labels of an answer counter.
#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
struct AnswerLabels {
    team: String,
    status: String,
    reason: String,
}

/// Labels of a per-team metric.
#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
struct TeamLabels {
    team: String,
}

/// Labels of a cold planner's wins.
#[derive(Debug, Clone, Hash, PartialEq, Eq, EncodeLabelSet)]
struct WinLabels {
    team: String,
    planner: String,
}

/// Latency buckets: 0.25 ms doubling to 512 ms.
fn latency_histogram() -> Histogram {
    Histogram::new(exponential_buckets(0.000_25, 2.0, 12))
}

/// Every team's metrics, and the registry they are encoded from.
pub struct Metrics {
    registry: Registry,
    answers: Family<AnswerLabels, Counter>,
    latency: Family<TeamLabels, Histogram, fn() -> Histogram>,
    late: Family<TeamLabels, Counter>,
    wins: Family<WinLabels, Counter>,
}

impl Default for Metrics {
    fn default() -> Self {
        let mut registry = Registry::with_prefix("flowopt");
        let answers = Family::<AnswerLabels, Counter>::default();
        registry.register("answers", "Answers published, by team, status and reason", answers.clone());
        let latency = Family::<TeamLabels, Histogram, fn() -> Histogram>::new_with_constructor(latency_histogram);
        registry.register(
            "answer_latency_seconds",
            "From a snapshot's arrival to its answer's publication",
            latency.clone(),
        );
        let late = Family::<TeamLabels, Counter>::default();
        registry.register("late_answers", "Answers published after the team's deadline", late.clone());
        let wins = Family::<WinLabels, Counter>::default();
        registry.register("cold_wins", "Cold plans adopted, by the planner that made them", wins.clone());
        Self { registry, answers, latency, late, wins }
    }
}

impl Metrics {
    /// The metrics of team `name`.
    pub fn team(&self, name: &str) -> TeamMetrics {
        let team = TeamLabels { team: name.to_string() };
        TeamMetrics {
            name: name.to_string(),
            answers: self.answers.clone(),
            seen: vec![None; 4 * REASONS],
            latency: self.latency.get_or_create(&team).clone(),
            late: self.late.get_or_create(&team).clone(),
            wins: self.wins.clone(),
            won: Vec::new(),
        }
    }

    /// The metrics as OpenMetrics text.
    pub fn encode(&self) -> String {
        let mut text = String::new();
        // Writing to a String cannot fail.
        let _ = encode(&mut text, &self.registry);
        text
    }
}

/// Reasons on the wire (`Reason` 0-23).
const REASONS: usize = 24;

/// One team's metrics, held by its worker.
pub struct TeamMetrics {
    name: String,
    answers: Family<AnswerLabels, Counter>,
    /// The answer counters met so far, by status and reason.
    seen: Vec<Option<Counter>>,
    latency: Histogram,
    late: Counter,
    wins: Family<WinLabels, Counter>,
    won: Vec<(&'static str, Counter)>,
}

impl TeamMetrics {
    /// Counts an answer of `status` for `reason`.
    pub fn answered(&mut self, status: PlanStatus, reason: Reason) {
        let slot = status as usize * REASONS + (reason as usize).min(REASONS - 1);
        let counter = self.seen[slot].get_or_insert_with(|| {
            let labels =
                AnswerLabels { team: self.name.clone(), status: format!("{status:?}"), reason: format!("{reason:?}") };
            self.answers.get_or_create(&labels).clone()
        });
        counter.inc();
    }

    /// Records the time from a snapshot's arrival to its answer, and
    /// whether that was past `deadline`.
    pub fn latency(&self, took: Duration, deadline: Duration) {
        self.latency.observe(took.as_secs_f64());
        if took > deadline {
            self.late.inc();
        }
    }

    /// Counts a cold plan made by `planner` and adopted.
    pub fn won(&mut self, planner: &'static str) {
        if let Some((_, counter)) = self.won.iter().find(|(p, _)| *p == planner) {
            counter.inc();
            return;
        }
        let labels = WinLabels { team: self.name.clone(), planner: planner.to_string() };
        let counter = self.wins.get_or_create(&labels).clone();
        counter.inc();
        self.won.push((planner, counter));
    }
}

/// Why the metrics endpoint cannot be served.
#[derive(Debug, Error)]
pub enum MetricsError {
    /// The address cannot be listened on.
    #[error("cannot serve metrics on {addr}: {source}")]
    Bind {
        /// The address.
        addr: SocketAddr,
        /// Why.
        source: std::io::Error,
    },
}

/// Serves `metrics` on `addr` (`GET /metrics`; anything else is 404) from
/// a thread of its own, for as long as the process lives. Returns the
/// address bound (`addr` with port 0 gets one from the system).
pub fn serve_metrics(addr: SocketAddr, metrics: Arc<Mutex<Metrics>>) -> Result<SocketAddr, MetricsError> {
    let bound = http::serve(addr, "metrics", "not found: the metrics are at /metrics\n", move |path| {
        (path == "/metrics").then(|| {
            let text = metrics.lock().map(|m| m.encode()).unwrap_or_default();
            ("application/openmetrics-text; version=1.0.0; charset=utf-8", text)
        })
    })
    .map_err(|source| MetricsError::Bind { addr, source })?;
    info!("metrics on http://{bound}/metrics");
    Ok(bound)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn get(addr: SocketAddr, path: &str) -> String {
        http::get(addr, path).unwrap()
    }

    #[test]
    fn answers_latency_and_wins_are_scraped() {
        let metrics = Arc::new(Mutex::new(Metrics::default()));
        let mut team = metrics.lock().unwrap().team("alpha");
        team.answered(PlanStatus::Ok, Reason::None);
        team.answered(PlanStatus::Ok, Reason::None);
        team.answered(PlanStatus::Held, Reason::DeadlineMissed);
        team.latency(Duration::from_millis(3), Duration::from_millis(20));
        team.latency(Duration::from_millis(25), Duration::from_millis(20));
        team.won("optimiser");
        let addr = serve_metrics("127.0.0.1:0".parse().unwrap(), Arc::clone(&metrics)).unwrap();
        let text = get(addr, "/metrics");
        assert!(text.starts_with("HTTP/1.1 200 OK"), "{text}");
        for line in [
            r#"flowopt_answers_total{team="alpha",status="Ok",reason="None"} 2"#,
            r#"flowopt_answers_total{team="alpha",status="Held",reason="DeadlineMissed"} 1"#,
            r#"flowopt_late_answers_total{team="alpha"} 1"#,
            r#"flowopt_cold_wins_total{team="alpha",planner="optimiser"} 1"#,
            r#"flowopt_answer_latency_seconds_count{team="alpha"} 2"#,
        ] {
            assert!(text.lines().any(|l| l == line), "{line} missing from\n{text}");
        }
        assert!(get(addr, "/other").starts_with("HTTP/1.1 404"));
    }
}
