//! Sharded evaluations (docs/cluster.md): which initial states shard K of N
//! holds ([`Shard`]) and the part a shard's evaluation writes ([`EvalPart`]).
//! Plain data shared by the evaluator (which writes parts), the worker
//! protocol (a worker host runs one shard of a server's job) and
//! `d3il_metrics::shard::merge` (which joins them).

use crate::{ProtocolManifest, RolloutRecord};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::ops::Range;
use std::str::FromStr;

/// The `format` of a part file; a part of another format is refused.
pub const PART_FORMAT: &str = "d3il-eval-part/1";

/// Shard `index` of `count` (1-based: `2/6` is the second of six).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Shard {
    pub index: usize,
    pub count: usize,
}

#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ShardError {
    #[error(
        "`{0}` is not a shard: write K/N with 1 <= K <= N, e.g. 2/6 for the second of six shards"
    )]
    Syntax(String),
    #[error(
        "shard {shard}: the protocol has only {n_contexts} initial states and a shard holds whole \
         initial states, so use at most {n_contexts} shards"
    )]
    TooManyShards { shard: Shard, n_contexts: usize },
}

impl fmt::Display for Shard {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.index, self.count)
    }
}

impl FromStr for Shard {
    type Err = ShardError;

    fn from_str(s: &str) -> Result<Self, ShardError> {
        let bad = || ShardError::Syntax(s.to_string());
        let (k, n) = s.split_once('/').ok_or_else(bad)?;
        let index: usize = k.trim().parse().map_err(|_| bad())?;
        let count: usize = n.trim().parse().map_err(|_| bad())?;
        if index == 0 || index > count {
            return Err(bad());
        }
        Ok(Shard { index, count })
    }
}

impl Shard {
    /// The initial states (indices into the protocol's first `n_contexts`)
    /// of this shard: shard k of N holds `[(k-1)·n/N, k·n/N)`, so the shards
    /// tile the set in order and differ in size by at most one.
    pub fn contexts(&self, n_contexts: usize) -> Result<Range<usize>, ShardError> {
        if self.count > n_contexts || self.index == 0 || self.index > self.count {
            return Err(ShardError::TooManyShards {
                shard: *self,
                n_contexts,
            });
        }
        let at = |k: usize| k * n_contexts / self.count;
        Ok(at(self.index - 1)..at(self.index))
    }
}

/// What `d3il eval --shard K/N --json part.json` writes: the protocol manifest
/// of the whole evaluation (task, policy sha256, initial-state set name and
/// sha256, seed, ...), which shard this is, and its rollouts.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EvalPart {
    /// [`PART_FORMAT`].
    pub format: String,
    pub manifest: ProtocolManifest,
    pub shard: Shard,
    /// The initial states covered, `[start, end)`.
    pub contexts: [usize; 2],
    /// Records in rollout order (initial state, then index within it).
    pub rollouts: Vec<RolloutRecord>,
    /// The metrics' behaviour key of each record (see [`crate::eval::assemble`]).
    pub behaviour_keys: Vec<Option<String>>,
    /// Wall-clock seconds in policy calls, and their number (inference time).
    pub policy_seconds: f64,
    pub policy_calls: usize,
    pub bootstrap_resamples: usize,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shards_tile_the_contexts_in_order() {
        for n in 1..=12 {
            for count in 1..=n {
                let mut next = 0;
                for index in 1..=count {
                    let r = Shard { index, count }.contexts(n).unwrap();
                    assert_eq!(r.start, next);
                    assert!(!r.is_empty());
                    next = r.end;
                }
                assert_eq!(next, n);
            }
        }
        let r = Shard { index: 2, count: 6 }.contexts(60).unwrap();
        assert_eq!(r, 10..20);
    }

    #[test]
    fn shard_syntax_and_limits() {
        assert_eq!("2/6".parse::<Shard>(), Ok(Shard { index: 2, count: 6 }));
        for bad in ["0/6", "7/6", "2", "a/b", "2/0", ""] {
            assert!(
                matches!(bad.parse::<Shard>(), Err(ShardError::Syntax(_))),
                "{bad}"
            );
        }
        let e = Shard { index: 1, count: 4 }.contexts(3).unwrap_err();
        assert!(e.to_string().contains("at most 3 shards"), "{e}");
    }
}
