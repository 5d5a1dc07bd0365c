//! Inference time of the BC-MLP-size fixture (assets/fixtures/aligning_mlp.onnx,
//! 20 -> 6x128 -> 3) for the Aligning protocol's batch of 480 rollouts: one batched
//! call versus 480 single-row calls, and the fixed-batch-1 export.
//!
//!     cargo run -p d3il-policy --example onnx_throughput [--release] [repeats]

use d3il_policy::{OnnxPolicy, Policy, Query};
use d3il_protocol::{PolicyManifest, TaskId, TaskSpec};
use std::time::Instant;

fn load(name: &str) -> OnnxPolicy {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets/fixtures");
    let bytes = std::fs::read(dir.join(format!("{name}.onnx"))).expect("fixture");
    let man: PolicyManifest =
        serde_json::from_slice(&std::fs::read(dir.join(format!("{name}.json"))).expect("manifest"))
            .expect("manifest parses");
    let spec = TaskSpec {
        task: TaskId::Aligning,
        obs_dim: 20,
        act_dim: 3,
        max_steps: 400,
        n_behaviours: 2,
    };
    OnnxPolicy::load(&bytes, &man, &spec, 0).expect("loads")
}

fn main() {
    let repeats: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(20);
    let b = 480;
    let ids: Vec<u64> = (0..b as u64).collect();
    let steps = vec![0u64; b];
    let obs: Vec<f32> = (0..b * 20).map(|i| (i % 17) as f32 * 0.01).collect();

    let mut p = load("aligning_mlp");
    let q = Query::new(&ids, &steps, &obs);
    p.infer(&q).expect("warm-up");
    let t = Instant::now();
    for _ in 0..repeats {
        p.infer(&q).expect("infer");
    }
    let batched = t.elapsed().as_secs_f64() / repeats as f64;

    let t = Instant::now();
    for _ in 0..repeats {
        for i in 0..b {
            let q1 = Query::new(&ids[i..i + 1], &steps[i..i + 1], &obs[i * 20..(i + 1) * 20]);
            p.infer(&q1).expect("infer");
        }
    }
    let single = t.elapsed().as_secs_f64() / repeats as f64;

    let mut p1 = load("aligning_mlp_batch1");
    let t = Instant::now();
    for _ in 0..repeats {
        p1.infer(&q).expect("infer");
    }
    let fixed1 = t.elapsed().as_secs_f64() / repeats as f64;

    println!("BC-MLP (20 -> 6x128 -> 3), {b} rollouts per lockstep query, {repeats} repeats");
    println!(
        "batched call        {:8.3} ms per query ({:6.2} us per rollout)",
        batched * 1e3,
        batched * 1e6 / b as f64
    );
    println!(
        "480 single calls    {:8.3} ms per query ({:6.2} us per rollout)",
        single * 1e3,
        single * 1e6 / b as f64
    );
    println!(
        "fixed batch-1 file  {:8.3} ms per query ({:6.2} us per rollout)",
        fixed1 * 1e3,
        fixed1 * 1e6 / b as f64
    );
    println!("batching speed-up   {:8.1}x", single / batched);
}
