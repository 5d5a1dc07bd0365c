//! One evaluation as the command line describes it, shared by `d3il eval`,
//! its robustness suite, `d3il race`, `d3il zoo reeval`, `d3il infer` and
//! `d3il submit`: the flags of `d3il eval` ([`EvalArgs`]), the job they make
//! (checked before anything slow), the policy manifest next to an ONNX file,
//! loading in process or running in a sandboxed worker, and the progress bar
//! and timing lines on stderr.

use anyhow::{bail, Context};
use d3il_evaluator::eval::{self, EvalOptions, PolicyInfo};
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::{
    Job, JobKind, ObsType, PolicyManifest, PolicySource, ProtocolKind, SuiteName, TaskId,
};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The flags of `d3il eval`: the task, the policy and how to evaluate it.
#[derive(clap::Args)]
pub struct EvalArgs {
    /// Task: avoiding, aligning, pushing, sorting-2/4/6, stacking, inserting.
    #[arg(long)]
    pub task: TaskId,
    /// `file.onnx` (manifest next to it as `file.json`, or --manifest),
    /// `ws://host:port/path` or `wss://host/path` for a remote endpoint, or `scripted:<name>`
    /// (e.g. `scripted:avoiding:all-paths`).
    #[arg(long)]
    pub policy: String,
    /// Manifest for an ONNX file (default: the .onnx path with .json).
    #[arg(long)]
    pub manifest: Option<PathBuf>,
    /// Seed of the evaluator's RNG (policy noise, bootstrap).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// `paper` (the full protocol of the D3IL paper) or `quick` (a smoke
    /// test on a few initial states).
    #[arg(long, default_value = "paper")]
    pub protocol: ProtocolKind,
    /// Write the full result (metrics, manifest, per-rollout records) here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Rollouts simulated at once.
    #[arg(long, default_value_t = 96)]
    pub max_live: usize,
    /// Run the evaluation in a sandboxed `d3il worker` process.
    #[arg(long)]
    pub sandbox: bool,
    /// Simulate every rollout also for a deterministic policy (no `noise`
    /// input), which is otherwise simulated once per initial state with the
    /// same results; for checking that (in process, not with --sandbox).
    #[arg(long, conflicts_with = "sandbox")]
    pub every_rollout: bool,
    /// Run N rollouts of each initial state instead of the protocol's (at
    /// most its number; numbered as a protocol of N rollouts numbers them):
    /// a sample of the protocol at a fraction of its cost, for measurements.
    /// The result's manifest records N; it is not the paper protocol. In
    /// process, not with --sandbox.
    #[arg(long, value_name = "N", conflicts_with = "sandbox", value_parser = clap::value_parser!(u32).range(1..))]
    pub rollouts_per_state: Option<u32>,
    /// Observation type of a remote endpoint (`state` or `image`); an ONNX
    /// policy's manifest says it itself.
    #[arg(long, default_value = "state")]
    pub obs_type: ObsType,
    /// Evaluate only shard K of N (contiguous blocks of whole initial states)
    /// and write a part file to --json; join the parts with `d3il merge`
    /// (docs/cluster.md).
    #[arg(long, value_name = "K/N")]
    pub shard: Option<d3il_evaluator::shard::Shard>,
    /// Limits of the sandboxed worker (--sandbox); the remote deadline and
    /// frame cap apply without --sandbox too. A remote endpoint may be on any
    /// address the user names, loopback and private ones included (only a
    /// server refuses those for submitted endpoints).
    #[command(flatten)]
    pub limits: super::flags::LimitArgs,
    /// `robustness`: also run every level of the task's perturbation suite
    /// (`assets/robustness/`) against level 0, the plain evaluation, and
    /// print the paired drops per axis and level (docs/robustness.md).
    #[arg(long, value_name = "robustness")]
    pub suite: Option<SuiteName>,
    /// Accepted and ignored: `d3il eval` connects to loopback and private
    /// addresses without it (command lines of older versions keep working).
    #[arg(long, hide = true)]
    pub allow_private_endpoints: bool,
}

fn progress_bar(done: usize, total: usize, started: Instant) {
    let frac = done as f64 / total.max(1) as f64;
    let width = 30;
    let filled = (frac * width as f64).round() as usize;
    let elapsed = started.elapsed().as_secs_f64();
    let eta = if done > 0 {
        elapsed / done as f64 * (total - done) as f64
    } else {
        f64::NAN
    };
    eprint!(
        "\r[{}{}] {done}/{total} rollouts, {elapsed:.0}s elapsed, ETA {}",
        "#".repeat(filled),
        " ".repeat(width - filled),
        if eta.is_finite() {
            format!("{eta:.0}s")
        } else {
            "?".into()
        }
    );
    let _ = std::io::stderr().flush();
}

/// A progress callback for an evaluation: redraws the bar on stderr when the
/// count of finished rollouts changes.
pub fn progress_printer() -> impl FnMut(usize, usize) {
    let started = Instant::now();
    let mut last = usize::MAX;
    move |d: usize, t: usize| {
        if d != last {
            last = d;
            progress_bar(d, t, started);
        }
    }
}

/// What an in-process evaluation of `job` needs: the task, the loaded policy
/// and the options (`d3il eval` without --sandbox, and each shard).
pub fn load_in_process(
    args: &EvalArgs,
    job: &Job,
) -> anyhow::Result<(
    LoadedTask,
    Box<dyn d3il_policy::Policy>,
    PolicyInfo,
    EvalOptions,
)> {
    let task = LoadedTask::load_obs(job.task, job.manifest.obs_type)?;
    let (policy, info) = d3il_evaluator::job::load_policy(job, &task)?;
    let opts = EvalOptions {
        protocol: job.protocol,
        seed: job.seed,
        max_live: args.max_live,
        simulate_every_rollout: args.every_rollout,
        build: job.build.clone(),
        rollouts_per_state: args.rollouts_per_state.map(|n| n as usize),
        ..EvalOptions::default()
    };
    Ok((task, policy, info, opts))
}

/// Ends the progress bar's line and prints where an evaluation's time went.
pub fn print_timing(t: &eval::Timing) {
    eprintln!();
    eprintln!(
        "time {:.1}s: stepping {:.1}s, policy {:.2}s over {} batched calls",
        t.total_s, t.physics_s, t.policy_s, t.policy_calls
    );
    if t.rollouts_simulated < t.rollouts {
        eprintln!(
            "deterministic policy (no `noise` input): each initial state was simulated once \
             and recorded for each of its rollouts ({} of {} rollouts simulated, same results)",
            t.rollouts_simulated, t.rollouts
        );
    }
}

/// The policy manifest of an ONNX file: `manifest` when given, else the
/// `.onnx` path with `.json` (`policy.onnx` -> `policy.json`). Returns its
/// path, text and parsed form. `d3il eval` and `d3il submit` both find it here.
pub fn read_manifest(
    onnx: &Path,
    manifest: Option<&Path>,
) -> anyhow::Result<(PathBuf, String, PolicyManifest)> {
    let mpath = manifest
        .map(Path::to_path_buf)
        .unwrap_or_else(|| onnx.with_extension("json"));
    let mtext = std::fs::read_to_string(&mpath).with_context(|| {
        format!(
            "reading the policy manifest {} (put it next to the .onnx file with the same name, or pass --manifest; format in docs/submission.md)",
            mpath.display()
        )
    })?;
    let parsed: PolicyManifest = serde_json::from_str(&mtext)
        .with_context(|| format!("{} is not a valid policy manifest", mpath.display()))?;
    Ok((mpath, mtext, parsed))
}

/// The job `args` describe, with everything about them checked that can be
/// checked without a simulation, a model load or this build's physics
/// fingerprint (a wrong name or file is refused at once, not after
/// a minute of fingerprinting): the scripted name, the endpoint URL, the ONNX
/// file and its manifest against the task, the shard and the output path.
/// `build` is left empty: [`load_then_fingerprint`] (or the caller, before a
/// sandboxed run) fills it in after the policy has loaded.
pub fn build_job(args: &EvalArgs) -> anyhow::Result<Job> {
    let def = d3il_evaluator::tasks::task_def(args.task)?;
    if let Some(path) = &args.json {
        super::check_output_path(path, "--json")?;
    }
    if let Some(shard) = args.shard {
        if args.json.is_none() {
            bail!("--shard {shard} needs --json FILE: the part file `d3il merge` joins with the other shards");
        }
        // Whole initial states of the protocol: at most that many shards.
        let set = def.context_set()?;
        let (n_ctx, _) = args
            .task
            .protocol_size(args.protocol, def.n_contexts_paper(set.len()));
        shard.contexts(n_ctx)?;
    }
    let (policy, manifest) = if let Some(name) = args.policy.strip_prefix("scripted:") {
        d3il_evaluator::scripted::ScriptedPolicy::from_name(name, def.spec_for(ObsType::State))?;
        (
            PolicySource::Scripted { name: name.into() },
            PolicyManifest {
                task: args.task,
                obs_type: ObsType::State,
                history: 1,
                horizon: 1,
                execute: 1,
                normalisation: None,
                window: Default::default(),
            },
        )
    } else if args.policy.starts_with("ws://") || args.policy.starts_with("wss://") {
        // The URL's form and its host's resolution; the user's own evaluation
        // may name loopback and private addresses.
        d3il_sandbox::validate_endpoint(&args.policy, true)?;
        (
            PolicySource::Remote {
                url: args.policy.clone(),
                // A server started with a secret serves only who sends it.
                secret: d3il_protocol::EndpointSecret::from_env().map_err(anyhow::Error::msg)?,
            },
            // k/H/E of a remote policy come from the server's hello.
            PolicyManifest {
                task: args.task,
                obs_type: args.obs_type,
                history: 1,
                horizon: 1,
                execute: 1,
                normalisation: None,
                window: Default::default(),
            },
        )
    } else {
        let path = PathBuf::from(&args.policy);
        if !path.is_file() {
            bail!(
                "--policy {}: no such file; give an ONNX file (its manifest next to it as .json, or --manifest), a ws:// or wss:// URL, or scripted:<name> ({})",
                path.display(),
                d3il_evaluator::scripted::names_for(args.task)
            );
        }
        let bytes = std::fs::read(&path).with_context(|| format!("reading {}", path.display()))?;
        let (mpath, _, manifest) = read_manifest(&path, args.manifest.as_deref())?;
        if manifest.task == args.task {
            manifest
                .validate_for(&def.spec_for(manifest.obs_type))
                .map_err(|e| anyhow::anyhow!("the manifest {}: {e}", mpath.display()))?;
        }
        let abs = std::fs::canonicalize(&path)?;
        (
            PolicySource::Onnx {
                path: abs.to_string_lossy().into_owned(),
                sha256: eval::sha256_hex(&bytes),
            },
            manifest,
        )
    };
    if manifest.task != args.task {
        bail!(
            "the manifest is for task `{}` but --task is `{}`",
            manifest.task,
            args.task
        );
    }
    if manifest.obs_type == ObsType::Image && !args.task.has_image_variant() {
        bail!(
            "task {} has no image variant (image tasks: aligning, sorting-4, sorting-6, stacking); evaluate a state policy",
            args.task
        );
    }
    Ok(Job {
        kind: JobKind::Plain,
        job_id: "cli".into(),
        task: args.task,
        protocol: args.protocol,
        policy,
        manifest,
        seed: args.seed,
        // The user's own evaluation reaches whatever they name.
        limits: args.limits.limits(true)?,
        assets_dir: super::assets_dir().to_string_lossy().into_owned(),
        dry_run_steps: None,
        build: None,
    })
}

/// The sandboxed `d3il worker` (this executable) that runs `job`: its wall
/// clock is the job's.
pub fn worker_command(job: &Job) -> anyhow::Result<d3il_sandbox::WorkerCommand> {
    Ok(d3il_sandbox::WorkerCommand {
        exe: std::env::current_exe()?,
        args: vec!["worker".into()],
        wall_clock: std::time::Duration::from_secs(job.limits.wall_seconds),
        max_output_bytes: 256 << 20,
    })
}

/// Runs `job` in a sandboxed `d3il worker` (as the server does), prints the
/// mechanisms in force and returns what it answered; a failure is an error.
pub fn sandboxed(
    job: &Job,
    on_progress: &mut dyn FnMut(usize, usize),
) -> anyhow::Result<d3il_sandbox::Outcome> {
    sandboxed_with(&worker_command(job)?, job, on_progress)
}

/// [`sandboxed`] with the worker command `cmd`.
pub fn sandboxed_with(
    cmd: &d3il_sandbox::WorkerCommand,
    job: &Job,
    on_progress: &mut dyn FnMut(usize, usize),
) -> anyhow::Result<d3il_sandbox::Outcome> {
    let run = d3il_sandbox::run_worker(cmd, job, on_progress);
    eprintln!();
    for m in &run.mechanisms {
        eprintln!(
            "sandbox: {} {} ({})",
            m.name,
            if m.active { "active" } else { "INACTIVE" },
            m.detail
        );
    }
    match run.outcome {
        d3il_sandbox::Outcome::Failed(e) => bail!("{:?}: {}", e.kind, e.message),
        other => Ok(other),
    }
}

/// Loads the task and the policy in process, runs the policy's test
/// inference, and only then computes this build's fingerprint (slow on a
/// fresh machine), so a model that cannot run is refused first. A remote
/// endpoint is connected to after the fingerprint instead: a connection left
/// idle for a minute can be closed by the server's keep-alive (its URL was
/// checked and its host resolved in [`build_job`]).
pub fn load_then_fingerprint(
    args: &EvalArgs,
    job: &mut Job,
) -> anyhow::Result<(
    LoadedTask,
    Box<dyn d3il_policy::Policy>,
    PolicyInfo,
    EvalOptions,
)> {
    if matches!(job.policy, PolicySource::Remote { .. }) {
        job.build = Some(super::build::this_build()?);
        return load_in_process(args, job);
    }
    let (task, mut policy, info, mut opts) = load_in_process(args, job)?;
    policy.self_test()?;
    job.build = Some(super::build::this_build()?);
    opts.build = job.build.clone();
    Ok((task, policy, info, opts))
}
