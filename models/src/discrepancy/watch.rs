//! What a workflow run shows while it works and when it stops searching
//! (`fdmlab discrepancy --time-limit`): each stage is announced as it starts, and
//! after the time limit no further effect is tried. The effects named by then are
//! still gated as usual ([`super::gate`]), so a stopped run names nothing that did
//! not earn its name; its report says where it stopped and what it skipped.

use serde::{Deserialize, Serialize};
use std::time::{Duration, Instant};

/// Progress callback and time limit of one run. `Watch::default()`: silent, no limit.
#[derive(Clone, Copy, Default)]
pub struct Watch<'a> {
    progress: Option<&'a (dyn Fn(&str) + Sync)>,
    /// The deadline (none when the limit is too far to represent) and the limit, s.
    limit: Option<(Option<Instant>, f64)>,
}

impl<'a> Watch<'a> {
    /// A watch calling `progress` with each stage's description; with `limit_s`, the
    /// search ends once that many seconds have passed from now (a negative or NaN limit
    /// counts as 0, an infinite one as none).
    pub fn new(progress: Option<&'a (dyn Fn(&str) + Sync)>, limit_s: Option<f64>) -> Self {
        let deadline = |s: f64| Duration::try_from_secs_f64(s.max(0.0)).ok().and_then(|d| Instant::now().checked_add(d));
        Watch { progress, limit: limit_s.map(|s| (deadline(s), s)) }
    }
    /// Announce a stage.
    pub fn stage(&self, what: &str) {
        if let Some(p) = self.progress {
            p(what);
        }
    }
    /// The instant after which no further effect is tried.
    pub fn deadline(&self) -> Option<Instant> {
        self.limit.and_then(|l| l.0)
    }
    /// Whether the limit has passed.
    pub fn expired(&self) -> bool {
        past(self.deadline())
    }
    /// Where the search stopped, if the limit has passed (`at`: the stage then).
    pub(crate) fn stopped(&self, at: &str, skipped: &[&str]) -> Option<Stopped> {
        let (_, limit_s) = self.limit?;
        self.expired().then(|| Stopped { limit_s, at: at.to_string(), skipped: skipped.iter().map(|s| s.to_string()).collect() })
    }
}

/// Where a run with a time limit stopped searching.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Stopped {
    /// The limit, s.
    pub limit_s: f64,
    /// The stage running when the limit passed (or the next one).
    pub at: String,
    /// Stages not run because of it.
    pub skipped: Vec<String>,
}

/// Whether `deadline` has passed: the check a domain's own long fits make between steps.
pub fn past(deadline: Option<Instant>) -> bool {
    deadline.is_some_and(|d| Instant::now() >= d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn odd_limits_neither_panic_nor_stop_wrongly() {
        assert!(Watch::new(None, Some(0.0)).expired());
        assert!(Watch::new(None, Some(-3.0)).expired());
        assert!(Watch::new(None, Some(f64::NAN)).expired());
        assert!(!Watch::new(None, Some(f64::INFINITY)).expired());
        assert!(!Watch::new(None, Some(1e300)).expired());
        assert!(!Watch::new(None, Some(3600.0)).expired());
        assert!(!Watch::default().expired());
    }
}
