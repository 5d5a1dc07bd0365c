//! The contract between the evaluator/worker (which know MuJoCo) and the
//! server/tables (which know HTTP and SQL). Everything here is plain serde data.

#![forbid(unsafe_code)]

pub mod address;
pub mod job;
pub mod paper;
pub mod results;
pub mod task;

pub use job::*;
pub use results::*;
pub use task::*;
