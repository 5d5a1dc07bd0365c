//! `d3il eval --suite robustness`: the robustness track (docs/robustness.md). Runs
//! level 0 (the plain evaluation, the control arm) and every level of the
//! task's perturbation suite on the same initial states, seed and rollout
//! ids, then prints per axis and level the paired drop against level 0 (the
//! machinery of `d3il compare`), the entropies and the success retained, and
//! the robustness score per axis and overall (docs/robustness.md).

use super::eval::Args;
use anyhow::{bail, Context};
use d3il_evaluator::eval::EvalOptions;
use d3il_evaluator::perturb::Suite;
use d3il_evaluator::robustness;
use d3il_evaluator::suite_shard::SuiteRun;
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::perturbation::{Axis, Perturbation};
use d3il_protocol::robustness::{RobustnessPart, RobustnessResult};
use d3il_protocol::{Estimate, Job, JobKind, SuiteName};

pub fn run(args: &Args, suite_name: SuiteName) -> anyhow::Result<()> {
    let mut job = super::eval::build_job(args)?;
    let suite = robustness::suite_for(suite_name, args.task, job.manifest.obs_type)?;
    if args.sandbox {
        return run_sandboxed(args, job, suite_name, &suite);
    }
    let (task, mut policy, info, opts) = super::eval::load_then_fingerprint(args, &mut job)?;
    let plan = robustness::plan(&task, policy.as_ref(), &opts, &suite)?;
    println!("{}", plan_line(&suite, &plan, &opts, None));
    let mut printer = Printer {
        progress: Box::new(super::eval::progress_printer()),
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
fn run_sandboxed(args: &Args, mut job: Job, name: SuiteName, suite: &Suite) -> anyhow::Result<()> {
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
    job.build = Some(super::verify::this_build()?);
    let (limits, cmd) = d3il_sandbox::suite_limits(
        &job.limits,
        &super::eval::worker_command(&job)?,
        plan.levels.len() + 1,
    );
    job.limits = limits;
    let mut on_progress = super::eval::progress_printer();
    match super::eval::sandboxed_with(&cmd, &job, &mut on_progress)? {
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
    args: &Args,
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
fn write_document(args: &Args, doc: &RobustnessResult) -> anyhow::Result<()> {
    print!("{}", render(doc));
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
        self.progress = Box::new(super::eval::progress_printer());
    }
    fn progress(&mut self, done: usize, total: usize) {
        (self.progress)(done, total)
    }
    fn level_finished(&mut self, timing: &d3il_evaluator::eval::Timing) {
        super::eval::print_timing(timing);
    }
}

fn interval(e: &Option<Estimate>) -> String {
    match e {
        Some(e) => match e.interval() {
            Some((lo, hi)) => format!("{:.3} [{lo:.3}, {hi:.3}]", e.value),
            None => format!("{:.3} ({})", e.value, e.interval_text(3)),
        },
        None => "— (no success at level 0)".into(),
    }
}

/// The tables: one per axis, a row per level (level 0 first).
pub fn render(doc: &RobustnessResult) -> String {
    let c = &doc.control;
    let m = &c.manifest;
    let mut s = format!(
        "robustness of {} ({} × {} rollouts, {} protocol, seed {}); suite {} (sha256 {})\n",
        m.task,
        m.n_contexts,
        m.rollouts_per_context,
        m.protocol.as_str(),
        m.seed,
        doc.suite,
        doc.suite_sha256
    );
    let head = format!(
        "{:<18} {:>7} {:>8}   {:<32} {:>8} {:>7} {:>7} {:>8}\n",
        "level", "success", "drop", "95% CI", "p", "H", "H|s0", "retained"
    );
    for a in &doc.axes {
        s += &format!("\n{}: score {}\n", a.axis, interval(&a.score));
        s += &head;
        s += &format!(
            "{:<18} {:>7.3} {:>8}   {:<32} {:>8} {:>7.3} {:>7.3} {:>8}\n",
            "0 (standard)",
            c.metrics.success_rate.value,
            "",
            "",
            "",
            c.metrics.behaviour_entropy.value,
            c.metrics.conditional_entropy.value,
            "1"
        );
        for l in doc.levels.iter().filter(|l| l.axis == a.axis) {
            let d = &l.paired.success_rate;
            s += &format!(
                "{:<18} {:>7.3} {:>+8.3}   {:<32} {:>8.4} {:>7.3} {:>7.3} {:>8}\n",
                format!("{} ({})", l.level, l.setting.label),
                l.result.metrics.success_rate.value,
                d.difference.value,
                super::compare::paired_interval_text(&d.difference),
                d.p_value,
                l.result.metrics.behaviour_entropy.value,
                l.result.metrics.conditional_entropy.value,
                l.retained
                    .map(|r| format!("{r:.3}"))
                    .unwrap_or_else(|| "—".into())
            );
        }
    }
    s += &format!("\noverall robustness score: {}\n", interval(&doc.overall));
    if let Some(c) = doc.score_coverage() {
        s += &format!("score intervals: {} (`d3il bench intervals`)\n", c.label);
    }
    let mut notes: Vec<String> = doc
        .levels
        .iter()
        .map(|l| l.paired.success_rate.interval_note())
        .collect();
    notes.sort();
    notes.dedup();
    for n in notes {
        s += &format!("drop: {n}\n");
    }
    let mut caveats: Vec<&String> = doc.levels.iter().flat_map(|l| &l.paired.caveats).collect();
    caveats.sort();
    caveats.dedup();
    for c in caveats {
        s += &format!("drop: note: {c}\n");
    }
    s += &format!(
        "drop: level 0 − level, paired by initial state (`d3il compare`, {} resamples); H: behaviour entropy; H|s0: conditional behaviour entropy; retained: share of level 0's successes kept, paired by initial state (Σ min(p0, p) / Σ p0, at most 1); score: retained averaged over the axis's levels (overall: over the axes), {:.0} % paired bootstrap interval (bias-corrected; for the score's expected value at this size; {})\n",
        doc.resamples,
        doc.confidence * 100.0,
        d3il_protocol::interval::score_coverage_note()
    );
    s
}

/// The evaluation of level `spec` (`AXIS/LEVEL`, e.g. `latency/2`; level 0
/// is the control) of a robustness document, as JSON for `d3il replay`.
pub fn level_text(text: &str, spec: &str) -> anyhow::Result<String> {
    let (axis, level) = spec
        .split_once('/')
        .with_context(|| format!("--level {spec}: give AXIS/LEVEL, e.g. latency/2"))?;
    let axis: Axis = axis.parse().map_err(|e: String| anyhow::anyhow!(e))?;
    let level: usize = level
        .parse()
        .with_context(|| format!("--level {spec}: the level is a number (0 is the control)"))?;
    let doc: RobustnessResult = serde_json::from_str(text)
        .context("--level reads a robustness document (`d3il eval --suite robustness --json`)")?;
    let result = doc.level(axis, level).with_context(|| {
        format!(
            "the document has no level {level} of {axis}; it has levels {}",
            doc.levels
                .iter()
                .map(|l| format!("{}/{}", l.axis, l.level))
                .collect::<Vec<_>>()
                .join(", ")
        )
    })?;
    Ok(serde_json::to_string(result)?)
}
