//! Shared helpers for the integration tests (included with `mod common;`).
#![allow(dead_code, unused_imports)] // each test file uses a subset

use d3il_protocol::{PolicyManifest, TaskId, TaskSpec};

pub use d3il_test_support::repo_dir as repo;

/// Dimensions from docs/original-d3il.md §10.5 (Avoiding 4/2, Aligning 20/3).
pub fn spec(task: TaskId) -> TaskSpec {
    let (obs_dim, act_dim, max_steps) = match task {
        TaskId::Avoiding => (4, 2, 250),
        TaskId::Aligning => (20, 3, 400),
        TaskId::Pushing => (10, 2, 400),
        other => panic!("no test spec for {other}"),
    };
    TaskSpec {
        task,
        obs_dim,
        act_dim,
        max_steps,
        n_behaviours: task.n_behaviours(),
    }
}

/// Bytes and manifest of a committed fixture in assets/fixtures.
pub fn fixture(name: &str) -> (Vec<u8>, PolicyManifest) {
    let bytes = std::fs::read(d3il_test_support::fixtures_dir().join(format!("{name}.onnx")))
        .unwrap_or_else(|e| panic!("fixture {name}.onnx: {e} (run scripts/make_fixtures.py)"));
    (bytes, d3il_test_support::fixture_manifest(name))
}
