//! Shared helpers for the integration tests (included with `mod common;`).
#![allow(dead_code)]

use d3il_protocol::{PolicyManifest, TaskId, TaskSpec};
use std::path::PathBuf;

pub fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..")
}

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
    let dir = repo().join("assets/fixtures");
    let bytes = std::fs::read(dir.join(format!("{name}.onnx")))
        .unwrap_or_else(|e| panic!("fixture {name}.onnx: {e} (run scripts/make_fixtures.py)"));
    let man: PolicyManifest = serde_json::from_slice(
        &std::fs::read(dir.join(format!("{name}.json"))).expect("fixture manifest"),
    )
    .expect("manifest parses");
    (bytes, man)
}
