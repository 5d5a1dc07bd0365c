//! `d3il race`: the sequential paired test of two policies (docs/sequential.md).
//!
//! * `d3il race --task T A B` races policies A and B on the same initial
//!   states in the same random order and stops when the test decides
//!   (`d3il_evaluator::eval::race`, the rule a server's race runs:
//!   `d3il submit --race A B`, `POST /api/v1/races`).
//! * `d3il race a.json b.json` replays the paired outcomes of two finished
//!   results in a seeded random order through the same test: when it would
//!   have stopped and what it would have saved.
//!
//! Both print the fixed-size comparison of the pairs used (the exact McNemar
//! test and its interval) as the race page does, with the same note that
//! neither holds after a data-dependent stop. (`d3il compare A B` is the
//! paired comparison of two finished results; `d3il compare --sequential`
//! is a deprecated alias of this command.)

use crate::common::evaluation::{build_job, load_in_process, EvalArgs};
use crate::common::text;
use anyhow::{bail, Context};
use d3il_evaluator::eval::race::{self, Contender, RaceOptions};
use d3il_protocol::{EvalResult, TaskId};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Clone)]
pub struct Args {
    /// Policy A, as `d3il eval --policy` takes it (ONNX file,
    /// `scripted:NAME`, `ws://…`); without `--task`, result A (`d3il eval
    /// --json a.json`) to replay.
    pub a: PathBuf,
    /// Policy B (or, without `--task`, result B, on the same task, protocol
    /// and initial states).
    pub b: PathBuf,
    /// Race the two policies on this task; without it, replay two results.
    #[arg(long)]
    pub task: Option<TaskId>,
    /// Level of the sequential test (two-sided).
    #[arg(long, default_value_t = 0.05)]
    pub alpha: f64,
    /// Also stop with "no difference larger than δ" when the confidence
    /// sequence of rate(A) − rate(B) lies inside (−δ, δ).
    #[arg(long)]
    pub delta: Option<f64>,
    /// Seed of the random order (and, with `--task`, of both policies' noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// With `--task`: `paper` or `quick`, the full size the race may run to.
    #[arg(long, default_value = "paper", requires = "task")]
    pub protocol: d3il_protocol::ProtocolKind,
    /// With `--task`: rollouts simulated at once per policy (fewer stop
    /// sooner after a decision, more run faster).
    #[arg(long, default_value_t = 8, requires = "task")]
    pub max_live: usize,
    /// Print the report as JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Races two policies (`--task`) or replays two results.
pub fn run(args: &Args) -> anyhow::Result<()> {
    match args.task {
        Some(task) => race_policies(args, task),
        None => replay(args),
    }
}

fn load(path: &Path) -> anyhow::Result<EvalResult> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| {
        format!(
            "{} is not an evaluation result; pass files written by `d3il eval --json FILE` (or race two policies with --task)",
            path.display()
        )
    })
}

fn replay(args: &Args) -> anyhow::Result<()> {
    d3il_protocol::race::check_race_params(args.alpha, args.delta)
        .map_err(|e| anyhow::anyhow!("--{}", e.message))?;
    let (a, b) = (load(&args.a)?, load(&args.b)?);
    let (pairs, per_state) = d3il_metrics::sequential::paired_outcomes_per_unit(&a, &b)?;
    let r = d3il_metrics::sequential::replay(&pairs, args.alpha, args.delta, args.seed);
    if args.json {
        let mut v = serde_json::to_value(&r)?;
        v["pair"] = (if per_state {
            "initial state"
        } else {
            "rollout"
        })
        .into();
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        if per_state {
            println!(
                "both policies did the same in every rollout of each initial state (deterministic): one pair per initial state"
            );
        }
        print!("{}", text::race_replay(&r));
    }
    Ok(())
}

/// `d3il eval`'s arguments for one side: the same policy forms and checks.
#[derive(clap::Parser)]
struct EvalCli {
    #[command(flatten)]
    args: EvalArgs,
}

fn side(args: &Args, task: TaskId, policy: &Path) -> anyhow::Result<EvalArgs> {
    let policy = policy.to_string_lossy().into_owned();
    let cli = <EvalCli as clap::Parser>::try_parse_from([
        "d3il eval".to_string(),
        "--task".into(),
        task.to_string(),
        "--policy".into(),
        policy.clone(),
        "--protocol".into(),
        args.protocol.as_str().into(),
        "--seed".into(),
        args.seed.to_string(),
        "--max-live".into(),
        args.max_live.to_string(),
    ])
    .map_err(|e| anyhow::anyhow!("policy {policy}: {e}"))?;
    Ok(cli.args)
}

fn race_policies(args: &Args, task: TaskId) -> anyhow::Result<()> {
    let race_opts = RaceOptions {
        alpha: args.alpha,
        delta: args.delta,
    };
    race_opts.check()?;
    if args.max_live == 0 {
        bail!("--max-live must be at least 1");
    }
    let (args_a, args_b) = (side(args, task, &args.a)?, side(args, task, &args.b)?);
    let (job_a, job_b) = (build_job(&args_a)?, build_job(&args_b)?);
    if job_a.manifest.obs_type != job_b.manifest.obs_type {
        bail!(
            "A takes {} observations and B {}: a race runs both on the same task variant",
            job_a.manifest.obs_type,
            job_b.manifest.obs_type
        );
    }
    let (task_a, mut policy_a, info_a, opts) = load_in_process(&args_a, &job_a)?;
    let (_, mut policy_b, info_b, _) = load_in_process(&args_b, &job_b)?;
    let quiet = args.json;
    let report = race::race(
        &task_a,
        Contender {
            policy: policy_a.as_mut(),
            info: &info_a,
        },
        Contender {
            policy: policy_b.as_mut(),
            info: &info_b,
        },
        &opts,
        &race_opts,
        &mut |p| {
            if !quiet {
                eprint!(
                    "\r{}/{} initial states, {} pairs, e-value {:.2}, anytime p {:.3}   ",
                    p.states, p.states_total, p.pairs, p.e_value, p.p_value
                );
            }
        },
    )?;
    if !quiet {
        eprintln!();
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", text::race(&report, &args.a, &args.b));
    }
    Ok(())
}
