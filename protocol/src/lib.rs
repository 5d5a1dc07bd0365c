//! The contract between the evaluator/worker (which know MuJoCo) and the
//! server/tables (which know HTTP and SQL). Everything here is plain serde data.

#![forbid(unsafe_code)]

pub mod address;
pub mod behaviour;
pub mod fidelity;
pub mod interval;
pub mod job;
pub mod paper;
pub mod perturbation;
pub mod progress;
pub mod race;
pub mod results;
pub mod robustness;
pub mod rollout;
pub mod shard;
pub mod task;

pub use behaviour::{behaviour_name, sorting_order};
pub use interval::{IntervalMethod, NoInterval, ScoreCoverage};
pub use job::*;
pub use progress::{Progress, StateOutcome};
pub use results::*;
pub use rollout::{Ending, Landmark, LandmarkKind, RolloutTrace};
pub use task::*;
