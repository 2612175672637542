//! The planning methods a user picks.

use std::fmt;
use std::str::FromStr;

use serde::{Deserialize, Serialize};

/// A planning method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Method {
    /// The learned pipeline and the from-scratch optimiser raced, each on a
    /// thread of its own: the first verified plan wins and the other is
    /// cancelled (the optimiser alone where the learned pipeline does not
    /// race: [`crate::build::members`]). The pipeline starts its safety
    /// filter from the samples, or from the initialiser where the settings
    /// name one.
    #[default]
    Auto,
    /// The from-scratch AM optimiser (smoothness cost, cold start).
    Baseline,
    /// The Flow-Opt pipeline (the paper's): flow samples, ranking, the SF
    /// initialiser (where there are obstacles), safety filter, selection.
    Flowopt,
    /// The pipeline with the SF started from the flow samples themselves
    /// (zero multiplier): the paper's ablation.
    FlowNoInit,
    /// The safety filter alone, repairing the optimiser's plan perturbed by
    /// noise of 10% of the separation on every coefficient (a benchmark of
    /// the filter: its time only).
    SafetyFilter,
}

impl Method {
    /// Every method.
    pub const ALL: [Method; 5] =
        [Method::Auto, Method::Baseline, Method::Flowopt, Method::FlowNoInit, Method::SafetyFilter];

    /// Its name on the command line, in settings and in reports.
    pub fn name(self) -> &'static str {
        match self {
            Method::Auto => "auto",
            Method::Baseline => "baseline",
            Method::Flowopt => "flowopt",
            Method::FlowNoInit => "flow-no-init",
            Method::SafetyFilter => "safety-filter",
        }
    }

    /// The names of every method.
    pub fn names() -> [&'static str; 5] {
        Self::ALL.map(Method::name)
    }

    /// Whether it runs the learned pipeline.
    pub fn learned(self) -> bool {
        matches!(self, Method::Auto | Method::Flowopt | Method::FlowNoInit)
    }
}

impl fmt::Display for Method {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Method {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|m| m.name() == s)
            .ok_or_else(|| format!("no method {s:?}: one of {}", Self::names().join(", ")))
    }
}
