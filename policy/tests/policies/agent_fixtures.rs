//! The agent fixtures of assets/fixtures/agents (scripts/make_agent_fixtures.py:
//! our own PyTorch modules shaped like each D3IL method family, exported with
//! torch.onnx.export) load, pass the admission test inference, and give the
//! actions onnxruntime gave on the same inputs (recorded in NAME.ort.json).

use crate::common;
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
}

/// A row's actions are a function of its own inputs (and, through the noise,
/// its rollout id and step) only: bit for bit the same whether it runs alone,
/// at any position of a batch of any size, on one thread or split across
/// several (the split, hence the host's core count, decides which rows share
/// a plan run). Before one-row batches were padded to two, a row that ran
/// alone went through tract's matrix–vector kernels and came out different.
#[test]
fn a_rows_actions_do_not_depend_on_its_company() {
    for name in names() {
        let (mut p, man) = load(&name);
        let s = p.shape();
        let (k, od, ad) = (man.history, s.obs_dim, s.act_dim);
        let row_obs = |r: usize| -> Vec<f32> {
            (0..k * od)
                .map(|i| ((i * 7 + r * 131) as f32 * 0.37).sin())
                .collect()
        };
        let row_prev = |r: usize| -> Vec<f32> {
            (0..(k - 1) * ad)
                .map(|i| ((i + r * 17) as f32 * 0.11).cos() * 0.004)
                .collect()
        };
        // Row 0 (rollout 42, step 9) alone on one thread is the reference.
        let run = |p: &mut OnnxPolicy, b: usize, at: usize| -> Vec<f32> {
            let ids: Vec<u64> = (0..b)
                .map(|r| if r == at { 42 } else { r as u64 })
                .collect();
            let steps = vec![9u64; b];
            let who = |r: usize| if r == at { 0 } else { r + 1 };
            let obs: Vec<f32> = (0..b).flat_map(|r| row_obs(who(r))).collect();
            let prev: Vec<f32> = (0..b).flat_map(|r| row_prev(who(r))).collect();
            let mut q = Query::new(&ids, &steps, &obs);
            q.window = Some(k);
            if p.takes_prev_actions() {
                q.prev_actions = Some(&prev);
            }
            p.infer(&q).unwrap().chunk(at).to_vec()
        };
        p.set_threads(1);
        let alone = run(&mut p, 1, 0);
        for threads in [1usize, 2, 3] {
            p.set_threads(threads);
            for (b, at) in [
                (1, 0),
                (2, 1),
                (3, 2),
                (5, 4),
                (13, 12),
                (13, 6),
                (49, 48),
                (96, 95),
            ] {
                let got = run(&mut p, b, at);
                assert!(
                    got.iter()
                        .zip(&alone)
                        .all(|(x, y)| x.to_bits() == y.to_bits()),
                    "{name}: row {at} of {b} on {threads} threads: {got:?}, alone {alone:?}"
                );
            }
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
