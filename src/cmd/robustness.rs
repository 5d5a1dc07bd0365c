//! `d3il eval --suite robustness`: the robustness track (docs/robustness.md). Runs
//! level 0 (the plain evaluation, the control arm) and every level of the
//! task's perturbation suite on the same initial states, seed and rollout
//! ids, then prints per axis and level the paired drop against level 0 (the
//! machinery of `d3il compare`), the entropies and the success retained, and
//! the robustness score per axis and overall (docs/robustness.md).

use crate::common::build::this_build;
use crate::common::evaluation::{
    build_job, load_then_fingerprint, print_timing, progress_printer, sandboxed_with,
    worker_command, EvalArgs,
};
use crate::common::text;
use anyhow::{bail, Context};
use d3il_evaluator::eval::EvalOptions;
use d3il_evaluator::perturb::Suite;
use d3il_evaluator::robustness;
use d3il_evaluator::suite_shard::SuiteRun;
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::perturbation::Perturbation;
use d3il_protocol::robustness::{RobustnessPart, RobustnessResult};
use d3il_protocol::{Job, JobKind, SuiteName};

pub fn run(args: &EvalArgs, suite_name: SuiteName) -> anyhow::Result<()> {
    let mut job = build_job(args)?;
    let suite = robustness::suite_for(suite_name, args.task, job.manifest.obs_type)?;
    if args.sandbox {
        return run_sandboxed(args, job, suite_name, &suite);
    }
    let (task, mut policy, info, opts) = load_then_fingerprint(args, &mut job)?;
    let plan = robustness::plan(&task, policy.as_ref(), &opts, &suite)?;
    println!("{}", plan_line(&suite, &plan, &opts, None));
    let mut printer = Printer {
        progress: Box::new(progress_printer()),
    };
    match d3il_evaluator::suite_shard::evaluate_suite_or_shard(
        &task,
        policy.as_mut(),
        &info,
        &opts,
        &suite,
        &plan,
        args.shard,
        &mut printer,
    )? {
        SuiteRun::Part(part) => write_part(args, &part, &plan),
        SuiteRun::Whole(doc) => write_document(args, &doc),
    }
}

/// `--suite robustness --sandbox`: the whole suite (or its shard) in one
/// sandboxed `d3il worker`, as a server's suite job runs it: the job with
/// `suite` (and `shard`), the worker's limits those of one evaluation
/// scaled to level 0 and every level (`d3il_sandbox::suite_limits`, the
/// rule the server's suite jobs use too). The policy is loaded only in the worker.
fn run_sandboxed(
    args: &EvalArgs,
    mut job: Job,
    name: SuiteName,
    suite: &Suite,
) -> anyhow::Result<()> {
    let task = LoadedTask::load_obs(job.task, job.manifest.obs_type)?;
    let opts = EvalOptions {
        protocol: job.protocol,
        ..EvalOptions::default()
    };
    // Deterministic or not is known once the worker has loaded the policy.
    let plan = robustness::plan_for(&task, false, &opts, suite)?;
    let once = robustness::plan_for(&task, true, &opts, suite)?;
    println!("{}", plan_line(suite, &plan, &opts, Some(once.simulated)));
    job.kind = JobKind::of(Some(name), args.shard);
    job.build = Some(this_build()?);
    let (limits, cmd) =
        d3il_sandbox::suite_limits(&job.limits, &worker_command(&job)?, plan.levels.len() + 1);
    job.limits = limits;
    let mut on_progress = progress_printer();
    match sandboxed_with(&cmd, &job, &mut on_progress)? {
        d3il_sandbox::Outcome::SuitePart(part) if args.shard.is_some() => {
            write_part(args, &part, &plan)
        }
        d3il_sandbox::Outcome::Robustness(doc) if args.shard.is_none() => {
            write_document(args, &doc)
        }
        _ => bail!("the worker did not answer the robustness job with its document or part"),
    }
}

/// The count up front: every level records the protocol's rollouts; a
/// deterministic policy simulates each state once, except under
/// observation noise (it differs from rollout to rollout).
/// `if_deterministic`: the plan is for a policy not known yet, and this is
/// what a deterministic one would simulate.
fn plan_line(
    suite: &Suite,
    plan: &robustness::SuitePlan,
    opts: &EvalOptions,
    if_deterministic: Option<usize>,
) -> String {
    format!(
        "robustness suite {} (sha256 {}): level 0 and {} perturbed levels on {} axes, each {} initial states × {} rollouts ({} protocol): {} rollouts recorded, {} simulated{}",
        suite.name,
        suite.sha256,
        plan.levels.len(),
        suite.file.axes.len(),
        plan.n_contexts,
        plan.rollouts_per_context,
        opts.protocol.as_str(),
        plan.recorded,
        plan.simulated,
        match if_deterministic {
            Some(n) => format!(
                " ({n} if the policy is deterministic: the sandboxed worker loads it and decides)"
            ),
            None if plan.once => " (deterministic policy: each initial state once, all rollouts under observation noise)".into(),
            None => String::new(),
        }
    )
}

/// Writes a shard's part file (`--shard K/N --json FILE`).
fn write_part(
    args: &EvalArgs,
    part: &RobustnessPart,
    plan: &robustness::SuitePlan,
) -> anyhow::Result<()> {
    // build_job checked the shard against the protocol and that --json is given.
    let path = args.json.as_ref().context("--shard needs --json FILE")?;
    std::fs::write(path, serde_json::to_vec_pretty(part)?)
        .with_context(|| format!("writing {}", path.display()))?;
    let [from, to] = part.control.contexts;
    println!(
        "task {} shard {}: initial states {from}..{to} of {} at level 0 and {} levels (merge all {} parts with `d3il merge`)",
        args.task,
        part.shard,
        plan.n_contexts,
        plan.levels.len(),
        part.shard.count
    );
    eprintln!("wrote {}", path.display());
    Ok(())
}

/// Prints the tables and writes the document to `--json`.
fn write_document(args: &EvalArgs, doc: &RobustnessResult) -> anyhow::Result<()> {
    print!("{}", text::robustness(doc));
    if let Some(path) = &args.json {
        std::fs::write(path, serde_json::to_vec_pretty(doc)?)
            .with_context(|| format!("writing {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

/// The CLI's view of a running suite: a line per level, the progress bar,
/// the timing.
struct Printer {
    progress: Box<dyn FnMut(usize, usize)>,
}

impl robustness::SuiteObserver for Printer {
    fn level_started(&mut self, level: Option<&Perturbation>) {
        match level {
            None => eprintln!("level 0 (standard protocol, the control arm)"),
            Some(p) => eprintln!("{} level {} ({})", p.axis, p.level, p.setting.label),
        }
        self.progress = Box::new(progress_printer());
    }
    fn progress(&mut self, done: usize, total: usize) {
        (self.progress)(done, total)
    }
    fn level_finished(&mut self, timing: &d3il_evaluator::eval::Timing) {
        print_timing(timing);
    }
}
