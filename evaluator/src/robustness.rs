//! A robustness evaluation (docs/robustness.md): level 0 (the plain
//! evaluation, the control arm) and every level of the task's perturbation
//! suite on the same initial states, seed and rollout ids, with each level's
//! paired drop against level 0 (`d3il compare`'s machinery) and the
//! robustness scores. `d3il eval --suite robustness` and a worker's job with
//! `suite` both run it.

use crate::eval::{self, evaluate, EvalError, EvalOptions, EvalRun, PolicyInfo, Timing};
use crate::perturb::Suite;
use crate::tasks::LoadedTask;
use d3il_metrics::suite_shard::SuiteLevels;
use d3il_policy::Policy;
use d3il_protocol::perturbation::{Axis, Perturbation};
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::{EvalResult, ObsType, SuiteName, TaskId};

/// Resamples of the paired comparisons and of the scores' intervals (as
/// `d3il compare`'s default).
pub use d3il_metrics::suite_shard::RESAMPLES;

/// The suite a job or `d3il eval --suite NAME` asks for, for `task` and
/// `obs`: every task has a state suite, and every image variant (Aligning,
/// Sorting-4/6, Stacking) an image suite with the camera and lighting
/// axes. The server checks the same before queueing, docs/robustness.md.
pub fn suite_for(name: SuiteName, task: TaskId, obs: ObsType) -> Result<Suite, EvalError> {
    match name {
        SuiteName::Robustness => {}
    }
    Suite::current(task, obs).map_err(|e| EvalError::Setup(e.to_string()))
}

/// How big a robustness evaluation is, before it runs.
#[derive(Debug, Clone)]
pub struct SuitePlan {
    pub levels: Vec<Perturbation>,
    pub n_contexts: usize,
    pub rollouts_per_context: usize,
    /// Whether a deterministic policy simulates each initial state once
    /// (except under observation noise, which differs per rollout).
    pub once: bool,
    /// Rollouts recorded over level 0 and every level.
    pub recorded: usize,
    /// Rollouts simulated over level 0 and every level.
    pub simulated: usize,
}

pub fn plan(
    task: &LoadedTask,
    policy: &dyn Policy,
    opts: &EvalOptions,
    suite: &Suite,
) -> Result<SuitePlan, EvalError> {
    plan_for(
        task,
        policy.deterministic() && !opts.simulate_every_rollout,
        opts,
        suite,
    )
}

/// [`plan`] for a policy that is deterministic (`once`: each initial state
/// simulated once) or not, without the policy (`d3il eval --suite
/// --sandbox` loads it only in the sandboxed worker).
pub fn plan_for(
    task: &LoadedTask,
    once: bool,
    opts: &EvalOptions,
    suite: &Suite,
) -> Result<SuitePlan, EvalError> {
    let levels = suite.perturbations();
    let set = task.def.context_set()?;
    let (n_ctx, per_ctx) = eval::run_size(task, opts, set.len());
    let per_level = n_ctx * per_ctx;
    let simulated = |noisy: bool| {
        if once && !noisy {
            n_ctx
        } else {
            per_level
        }
    };
    let sim_total = simulated(false)
        + levels
            .iter()
            .map(|p| simulated(p.axis == Axis::ObsNoise))
            .sum::<usize>();
    Ok(SuitePlan {
        n_contexts: n_ctx,
        rollouts_per_context: per_ctx,
        once,
        recorded: per_level * (levels.len() + 1),
        simulated: sim_total,
        levels,
    })
}

/// What a caller sees of a running robustness evaluation.
pub trait SuiteObserver {
    /// Before a level (None: level 0).
    fn level_started(&mut self, _level: Option<&Perturbation>) {}
    /// Progress within the current level.
    fn progress(&mut self, done: usize, total: usize);
    fn level_finished(&mut self, _timing: &Timing) {}
}

/// Runs level 0 and every level of `plan`, and builds the document.
pub fn evaluate_suite(
    task: &LoadedTask,
    policy: &mut dyn Policy,
    info: &PolicyInfo,
    opts: &EvalOptions,
    suite: &Suite,
    plan: &SuitePlan,
    observer: &mut dyn SuiteObserver,
) -> Result<RobustnessResult, EvalError> {
    observer.level_started(None);
    let mut counts = |d, n| observer.progress(d, n);
    let (control, t) = evaluate(
        task,
        policy,
        info,
        opts,
        EvalRun::all().counting(&mut counts),
    )?;
    observer.level_finished(&t);
    let mut results: Vec<(Perturbation, EvalResult)> = vec![];
    for p in &plan.levels {
        observer.level_started(Some(p));
        let mut counts = |d, n| observer.progress(d, n);
        let run = EvalRun::all().perturbed(p).counting(&mut counts);
        let (r, t) = evaluate(task, policy, info, opts, run)?;
        observer.level_finished(&t);
        results.push((p.clone(), r));
    }
    document(suite, control, results)
}

/// The robustness document of level 0's result and every level's (in the
/// suite's order): each level's paired drop against level 0 and the scores,
/// bootstrapped with the evaluation's seed. An evaluation here and the
/// merge of its shards (`d3il_metrics::suite_shard`) build it the same way.
pub fn document(
    suite: &Suite,
    control: EvalResult,
    levels: Vec<(Perturbation, EvalResult)>,
) -> Result<RobustnessResult, EvalError> {
    let seed = control.manifest.seed;
    assemble(suite, control, levels, seed).map_err(EvalError::from)
}

/// The robustness document of level 0 (`control`) and the levels'
/// results (`d3il_metrics::suite_shard::document`, with `suite`'s name,
/// sha256 and axes): each level's paired drop against level 0, seeded by
/// `seed`, the success retained and the scores per axis and overall.
pub fn assemble(
    suite: &Suite,
    control: EvalResult,
    results: Vec<(Perturbation, EvalResult)>,
    seed: u64,
) -> Result<RobustnessResult, d3il_metrics::MetricsError> {
    d3il_metrics::suite_shard::document(&suite_levels(suite), control, results, seed)
}

/// What a robustness document records of `suite`: its name and sha256, its
/// axes and its levels, in the file's order.
pub fn suite_levels(suite: &Suite) -> SuiteLevels {
    SuiteLevels {
        name: suite.name.clone(),
        sha256: suite.sha256.clone(),
        axes: suite.file.axes.iter().map(|a| a.axis).collect(),
        levels: suite.perturbations(),
    }
}

/// Progress over the whole suite for a worker: level by level, counted
/// against the rollouts of every level.
pub struct Cumulative<'a> {
    pub on_progress: &'a mut dyn FnMut(usize, usize),
    pub total: usize,
    done_before: usize,
    level_total: usize,
}

impl<'a> Cumulative<'a> {
    pub fn new(on_progress: &'a mut dyn FnMut(usize, usize), total: usize) -> Self {
        Cumulative {
            on_progress,
            total,
            done_before: 0,
            level_total: 0,
        }
    }
}

impl SuiteObserver for Cumulative<'_> {
    fn level_started(&mut self, _level: Option<&Perturbation>) {
        self.done_before += self.level_total;
        self.level_total = 0;
    }
    fn progress(&mut self, done: usize, total: usize) {
        self.level_total = total;
        (self.on_progress)(
            self.done_before + done,
            self.total.max(self.done_before + total),
        );
    }
}
