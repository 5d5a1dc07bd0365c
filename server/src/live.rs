//! The success rate of an evaluation so far, with its confidence
//! sequence (`d3il_metrics::sequential::BettingCs`), valid at every look:
//! what the submission page, the API and the client show while an evaluation
//! runs, and what a cancelled evaluation keeps.

use crate::store::{StateOutcome, Store, StoreError};
use d3il_metrics::sequential::BettingCs;
use serde::Serialize;
use utoipa::ToSchema;

/// The level of the live confidence sequence (as the fixed-size intervals').
pub const LIVE_ALPHA: f64 = 0.05;

/// The success rate so far and its anytime-valid confidence sequence.
#[derive(Debug, Clone, Serialize, ToSchema)]
pub struct LiveEstimate {
    /// Initial states finished so far: the unit of the confidence sequence
    /// (one value per state: the fraction of its rollouts that succeeded).
    pub states: u64,
    pub rollouts: u64,
    pub successes: u64,
    /// Successes / rollouts so far (null before the first state finished).
    pub success_rate: Option<f64>,
    /// The confidence sequence at this look: it covers the true success
    /// rate at every look, however often and whenever someone looks, with
    /// probability at least 1 − alpha. (0, 1) before the first state.
    pub cs_low: f64,
    pub cs_high: f64,
    pub alpha: f64,
    /// Always true: the interval is a confidence sequence, not a fixed-size
    /// interval (that one comes with the finished result).
    pub valid_at_every_look: bool,
    /// The evaluation was cancelled: these are all the outcomes it has.
    pub partial: bool,
}

/// The order in which the outcomes of a sharded evaluation enter the
/// sequence: the shards' lists taken in turn (first of each shard, then the
/// second of each, ...): a rule fixed before any outcome is seen.
pub fn interleave(shards: &[Vec<StateOutcome>]) -> Vec<StateOutcome> {
    let longest = shards.iter().map(Vec::len).max().unwrap_or(0);
    (0..longest)
        .flat_map(|i| shards.iter().filter_map(move |s| s.get(i).copied()))
        .collect()
}

/// The estimate from the outcomes in the order they were reported.
pub fn estimate(outcomes: &[StateOutcome], partial: bool) -> LiveEstimate {
    let mut cs = BettingCs::new(LIVE_ALPHA);
    let (mut rollouts, mut successes) = (0u64, 0u64);
    for o in outcomes.iter().filter(|o| o.rollouts > 0) {
        let k = o.successes.min(o.rollouts);
        cs.update(k as f64 / o.rollouts as f64);
        rollouts += o.rollouts as u64;
        successes += k as u64;
    }
    let (cs_low, cs_high) = cs.interval();
    LiveEstimate {
        states: cs.n(),
        rollouts,
        successes,
        success_rate: (rollouts > 0).then(|| successes as f64 / rollouts as f64),
        cs_low,
        cs_high,
        alpha: cs.alpha(),
        valid_at_every_look: true,
        partial,
    }
}

/// The live estimate of a submission: None until an outcome was reported
/// (and for evaluations run before outcomes were reported).
pub async fn live_estimate(
    store: &Store,
    submission_id: i64,
    partial: bool,
) -> Result<Option<LiveEstimate>, StoreError> {
    let shards = store.outcomes_of(submission_id).await?;
    let outcomes = interleave(&shards);
    Ok((!outcomes.is_empty()).then(|| estimate(&outcomes, partial)))
}

/// The states a running attempt has reported, as the pool collects them
/// from its progress reports and writes them with its heartbeats.
#[derive(Debug, Default)]
pub struct Reported {
    outcomes: Vec<StateOutcome>,
    unwritten: bool,
}

impl Reported {
    /// Adds the states newly finished (reported in the evaluation's random
    /// order, each once).
    pub fn add(&mut self, p: &d3il_protocol::Progress) {
        for s in &p.states {
            self.outcomes.push(StateOutcome {
                successes: s.successes.iter().filter(|x| **x).count() as u32,
                rollouts: s.successes.len() as u32,
            });
            self.unwritten = true;
        }
    }

    /// Writes them if something new came (a lost lease writes nothing).
    pub async fn flush(&mut self, store: &Store, job_id: i64, owner: &str) {
        if !self.unwritten {
            return;
        }
        match store.record_outcomes(job_id, owner, &self.outcomes).await {
            Ok(_) => self.unwritten = false,
            Err(e) => tracing::warn!(
                "job {job_id}: outcomes not written ({e}); retried with the next heartbeat"
            ),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn o(successes: u32, rollouts: u32) -> StateOutcome {
        StateOutcome {
            successes,
            rollouts,
        }
    }

    #[test]
    fn shards_are_taken_in_turn() {
        let s = interleave(&[vec![o(1, 1), o(0, 1), o(1, 1)], vec![o(2, 2)]]);
        assert_eq!(s, vec![o(1, 1), o(2, 2), o(0, 1), o(1, 1)]);
    }

    #[test]
    fn estimate_is_the_betting_sequence_of_per_state_fractions() {
        let outcomes = [o(8, 8), o(4, 8), o(0, 8), o(8, 8)];
        let e = estimate(&outcomes, false);
        let mut cs = BettingCs::new(LIVE_ALPHA);
        for x in [1.0, 0.5, 0.0, 1.0] {
            cs.update(x);
        }
        assert_eq!((e.cs_low, e.cs_high), cs.interval());
        assert_eq!((e.states, e.rollouts, e.successes), (4, 32, 20));
        assert_eq!(e.success_rate, Some(20.0 / 32.0));
        assert!(e.cs_low <= 0.625 && 0.625 <= e.cs_high, "{e:?}");
        let none = estimate(&[], true);
        assert_eq!(
            (none.cs_low, none.cs_high, none.success_rate),
            (0.0, 1.0, None)
        );
        assert!(none.partial && none.valid_at_every_look);
    }
}
