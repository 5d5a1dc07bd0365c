//! The subcommands of `d3il`, one module each (`Args` and `run`). A command
//! module uses `crate::common` and the library crates, never another
//! command's module (test-support/tests/layout.rs checks it).

pub mod compare;
pub mod contexts;
pub mod db;
pub mod demos;
pub mod eval;
pub mod fidelity;
pub mod infer;
pub mod intervals;
pub mod merge;
pub mod race;
pub mod render;
pub mod replay;
pub mod robustness;
pub mod serve;
pub mod submit;
pub mod tables;
pub mod token;
pub mod verify;
pub mod worker;
pub mod workers;
pub mod zoo;
