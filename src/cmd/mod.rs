//! The subcommands of `d3il`, one module each (`Args` and `run`). A command
//! module uses `crate::common` and the library crates, never another
//! command's module (test-support/tests/layout.rs checks it).

pub mod bench;
pub mod bench_chaos;
pub mod bench_intervals;
pub mod bench_procs;
pub mod bench_robustness;
pub mod bench_scale;
pub mod bench_scripts;
pub mod bench_sequential;
pub mod bench_serve;
pub mod bench_served_agent;
pub mod bench_video;
pub mod compare;
pub mod contexts;
pub mod db;
pub mod demos;
pub mod eval;
pub mod fidelity;
pub mod fixtures;
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
