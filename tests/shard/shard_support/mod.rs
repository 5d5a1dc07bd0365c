//! What the sharding tests share: the comparison of a merged result with
//! a plain `d3il eval --json` result.

// Each test binary that includes this module uses a part of it.
#![allow(dead_code)]

use d3il_protocol::EvalResult;
use serde_json::Value;
use std::path::Path;

pub fn read_result(path: &Path) -> EvalResult {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// The table without the (measured, hence differing) inference-time line.
pub fn table(stdout: &str) -> Vec<&str> {
    stdout
        .lines()
        .filter(|l| !l.starts_with("inference ms per call"))
        .collect()
}

pub fn assert_same_result(plain: &Path, merged: &Path) {
    let (mut a, mut b) = (read_result(plain), read_result(merged));
    assert!(a.metrics.inference_ms > 0.0 && b.metrics.inference_ms > 0.0);
    a.metrics.inference_ms = 0.0;
    b.metrics.inference_ms = 0.0;
    assert_eq!(a.rollouts.len(), 6);
    assert_eq!(a, b);
    // Bit for bit in the file too (serde_json writes floats round-trip exact).
    let strip = |p: &Path| {
        let mut v: Value = serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap();
        v["metrics"]["inference_ms"] = Value::Null;
        serde_json::to_string(&v).unwrap()
    };
    assert_eq!(strip(plain), strip(merged));
    // The policy really acts by rollout id: the 6 rollouts do not all behave alike.
    let behaviours: std::collections::BTreeSet<String> =
        a.rollouts.iter().map(|r| r.behaviour.to_string()).collect();
    assert!(behaviours.len() > 1, "{behaviours:?}");
}
