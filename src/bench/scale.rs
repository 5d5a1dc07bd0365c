//! `d3il bench scale`: one evaluation (the Aligning BC-MLP fixture with a
//! noise input, so all rollouts are simulated as for a stochastic policy; paper
//! protocol by default) split into shards on a PostgreSQL queue, run by 1 and
//! then by N local worker hosts (`d3il workers`, each pinned to its own core
//! with `taskset`, so a host stands for a one-core machine). Prints both wall
//! times; the last line is `ratio <speed-up / N>` (goal: at least 0.85 on 2).
//!
//! The queue is a throw-away PostgreSQL cluster (`d3il_pgtemp`), a fresh
//! database per run; the hosts are the real `d3il workers` with sandboxed
//! `d3il worker` processes. The time runs from queueing the submission to its
//! merged result.

use super::procs::{spawn_ready, Proc};
use anyhow::{bail, ensure, Context};
use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use d3il_server::ops::{DbTarget, NewMethod, NewPolicy, NewSubmission, Store, SubmissionStatus};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Stochastic (it takes `noise`): a deterministic policy would be simulated
/// once per initial state, an eighth of the work this bench is about.
const FIXTURE: &str = "fixtures/aligning_mlp_noise";

pub fn run(protocol: ProtocolKind, hosts: usize, shards: usize) -> anyhow::Result<()> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    ensure!(
        (2..=cores).contains(&hosts),
        "--hosts {hosts}: each worker host gets a core of its own, so use 2 to {cores} hosts on this machine"
    );
    ensure!(
        shards >= hosts,
        "--shards {shards}: give each of the {hosts} hosts at least one shard"
    );
    Command::new("taskset")
        .arg("-V")
        .output()
        .context("`taskset` (util-linux) pins each worker host to a core; install util-linux")?;
    let dir = std::env::temp_dir().join(format!("d3il-bench-scale-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let result = bench(&dir, protocol, hosts, shards);
    let _ = std::fs::remove_dir_all(&dir);
    result
}

fn bench(dir: &Path, protocol: ProtocolKind, hosts: usize, shards: usize) -> anyhow::Result<()> {
    eprintln!(
        "Aligning BC-MLP fixture with noise, {protocol:?} protocol, {shards} shards, worker hosts pinned to one core each"
    );
    let one = timed_run(&dir.join("one"), protocol, 1, shards)?;
    println!("1 host:  {one:.1} s");
    let many = timed_run(&dir.join("many"), protocol, hosts, shards)?;
    println!("{hosts} hosts: {many:.1} s");
    let speedup = one / many;
    println!("speed-up {speedup:.2} on {hosts} hosts");
    println!("ratio {:.3}", speedup / hosts as f64);
    Ok(())
}

/// A `d3il workers` process pinned to one core (killed on drop).
fn start_host(url: &str, store: &Path, core: usize) -> anyhow::Result<Proc> {
    let exe = std::env::current_exe().context("finding the d3il executable")?;
    let mut cmd = Command::new("taskset");
    cmd.args(["-c", &core.to_string()])
        .arg(exe)
        .args(["workers", "--db", url, "--policy-store"])
        .arg(store)
        .args(["--workers", "1"])
        .stderr(Stdio::null());
    let what = format!("d3il workers on core {core}");
    Ok(spawn_ready(cmd, "worker host ready", &what)?.0)
}

/// Seconds from queueing the sharded submission to its merged result, with
/// `hosts` worker hosts on cores 0..hosts.
fn timed_run(
    dir: &Path,
    protocol: ProtocolKind,
    hosts: usize,
    shards: usize,
) -> anyhow::Result<f64> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let url = d3il_pgtemp::fresh_database();
    let policies = dir.join("policy-store");
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()?;
    let store = rt.block_on(Store::connect(
        &DbTarget::Postgres(url.clone()),
        Some(&policies),
    ))?;
    let running: Vec<Proc> = (0..hosts)
        .map(|core| start_host(&url, &policies, core))
        .collect::<anyhow::Result<_>>()?;
    let t0 = Instant::now();
    let id = rt.block_on(queue(&store, protocol, shards))?;
    loop {
        let s = rt.block_on(store.submission(id))?;
        match s.status {
            SubmissionStatus::Completed => break,
            SubmissionStatus::Failed => bail!(
                "the benchmark evaluation failed: {}",
                s.error_message.unwrap_or_default()
            ),
            _ => std::thread::sleep(Duration::from_millis(200)),
        }
    }
    let secs = t0.elapsed().as_secs_f64();
    drop(running);
    Ok(secs)
}

/// Stores the fixture as an uploaded policy and queues its evaluation in
/// `shards` shards.
async fn queue(store: &Store, protocol: ProtocolKind, shards: usize) -> anyhow::Result<i64> {
    let assets = crate::common::assets_dir();
    let onnx = assets.join(format!("{FIXTURE}.onnx"));
    let bytes = std::fs::read(&onnx).with_context(|| format!("reading {}", onnx.display()))?;
    let manifest = std::fs::read_to_string(assets.join(format!("{FIXTURE}.json")))?;
    let sha = d3il_evaluator::tasks::contexts::sha256_hex(&bytes);
    let tmp = store.new_upload_path();
    std::fs::write(&tmp, &bytes).with_context(|| format!("writing {}", tmp.display()))?;
    let (path, _) = store.commit_onnx(&tmp, &sha).await?;
    let method = store
        .ensure_method(
            &NewMethod {
                name: "Scale-Bench".into(),
                ..Default::default()
            },
            None,
        )
        .await?;
    Ok(store
        .create_submission_sharded(
            &NewSubmission {
                method_id: method.id,
                submitter_id: None,
                task: TaskId::Aligning,
                obs_type: ObsType::State,
                training_seed: 0,
                data_fraction: 1.0,
                protocol,
                policy: NewPolicy::Onnx {
                    sha256: sha,
                    bytes: bytes.len() as i64,
                    path,
                },
                manifest_json: manifest,
                simulated_once: None,
            },
            1,
            shards,
        )
        .await?)
}
