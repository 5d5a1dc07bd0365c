//! The agent fixtures of assets/fixtures/agents (scripts/make_agent_fixtures.py:
//! our own PyTorch modules shaped like each D3IL method family, exported with
//! torch.onnx.export) load, pass the admission test inference, and give the
//! actions onnxruntime gave on the same inputs (recorded in NAME.ort.json).

mod common;
use common::spec;
use d3il_policy::{OnnxPolicy, Policy, Query, WindowMode};
use d3il_protocol::{PolicyManifest, TaskId};
use serde_json::Value;

const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/fixtures/agents/");

fn names() -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(DIR)
        .unwrap()
        .filter_map(|e| {
            let n = e.unwrap().file_name().into_string().unwrap();
            n.strip_suffix(".onnx").map(str::to_string)
        })
        .collect();
    v.sort();
    v
}

fn load(name: &str) -> (OnnxPolicy, PolicyManifest) {
    let bytes = std::fs::read(format!("{DIR}{name}.onnx")).unwrap();
    let man: PolicyManifest =
        serde_json::from_str(&std::fs::read_to_string(format!("{DIR}{name}.json")).unwrap())
            .unwrap();
    let p = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Aligning), 0)
        .unwrap_or_else(|e| panic!("{name}: {e}"));
    (p, man)
}

fn floats(v: &Value) -> Vec<f32> {
    v["data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect()
}

#[test]
fn every_method_family_is_there() {
    let n = names();
    for want in [
        "bc_mlp",
        "vae_act",
        "bet",
        "ibc",
        "ddpm_mlp",
        "ddpm_transformer",
        "ddpm_act",
        "beso",
    ] {
        assert!(n.iter().any(|x| x == want), "{want} missing from {n:?}");
    }
}

#[test]
fn tract_matches_onnxruntime_on_recorded_inputs() {
    for name in names() {
        let (p, man) = load(&name);
        let rec: Value = serde_json::from_str(
            &std::fs::read_to_string(format!("{DIR}{name}.ort.json")).unwrap(),
        )
        .unwrap();
        let cases = rec["cases"].as_array().unwrap();
        let want_cases = if man.window == WindowMode::Grow {
            man.history
        } else {
            1
        };
        assert_eq!(cases.len(), want_cases, "{name}");
        for c in cases {
            let w = c["window"].as_u64().unwrap() as usize;
            let ins = &c["inputs"];
            let obs = floats(&ins["obs"]);
            let b = ins["obs"]["shape"][0].as_u64().unwrap() as usize;
            let prev = ins.get("prev_actions").map(floats);
            let noise = ins.get("noise").map(floats);
            let got = p
                .run_explicit(b, w, &obs, prev.as_deref(), noise.as_deref())
                .unwrap_or_else(|e| panic!("{name} window {w}: {e}"));
            let want = floats(&c["actions"]);
            assert_eq!(got.len(), want.len(), "{name} window {w}");
            let worst = got
                .iter()
                .zip(&want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(
                worst <= 1e-6,
                "{name} window {w}: tract differs from onnxruntime by {worst:e}"
            );
        }
    }
}

#[test]
fn growing_windows_and_prev_actions_reach_the_graph() {
    let (mut p, man) = load("beso");
    assert_eq!(p.window(), WindowMode::Grow);
    assert!(p.takes_prev_actions());
    // Every window length runs, with its matching number of previous actions,
    // at several batch sizes (plans per bucket, split across threads).
    for b in [1usize, 5, 13] {
        let ids: Vec<u64> = (0..b as u64).collect();
        let steps = vec![3u64; b];
        for w in 1..=man.history {
            let obs = vec![0.1f32; b * w * 20];
            let prev = vec![0.001f32; b * (w - 1) * 3];
            let mut q = Query::new(&ids, &steps, &obs);
            q.window = Some(w);
            q.prev_actions = Some(&prev);
            let a = p.infer(&q).unwrap();
            assert_eq!(a.data.len(), b * 3);
            assert!(a.data.iter().all(|x| x.is_finite()));
        }
    }
    // Results do not depend on how the batch was split: row r is the same alone.
    let ids = [7u64, 8, 9, 10, 11];
    let steps = [0u64; 5];
    let obs: Vec<f32> = (0..5 * 2 * 20).map(|i| (i as f32 * 0.37).sin()).collect();
    let prev: Vec<f32> = (0..5 * 3)
        .map(|i| (i as f32 * 0.11).cos() * 0.004)
        .collect();
    let mut q = Query::new(&ids, &steps, &obs);
    q.window = Some(2);
    q.prev_actions = Some(&prev);
    let all = p.infer(&q).unwrap();
    p.set_threads(1);
    for r in 0..5 {
        let mut one = Query::new(&ids[r..r + 1], &steps[r..r + 1], &obs[r * 40..(r + 1) * 40]);
        one.window = Some(2);
        one.prev_actions = Some(&prev[r * 3..(r + 1) * 3]);
        let a = p.infer(&one).unwrap();
        for (x, y) in a.data.iter().zip(all.chunk(r)) {
            assert!((x - y).abs() <= 1e-6, "row {r}: {x} vs {y}");
        }
    }
}

#[test]
fn grow_is_refused_for_a_fixed_window() {
    let bytes = std::fs::read(format!("{DIR}ddpm_transformer.onnx")).unwrap();
    let mut man: PolicyManifest = serde_json::from_str(
        &std::fs::read_to_string(format!("{DIR}ddpm_transformer.json")).unwrap(),
    )
    .unwrap();
    man.window = WindowMode::Grow;
    let e = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Aligning), 0).unwrap_err();
    let m = e.to_string();
    assert!(
        m.contains("fixed window dimension 5") && m.contains("\"window\": \"pad\""),
        "{m}"
    );
}
