//! A robustness evaluation in shards (docs/robustness.md):
//! `d3il eval --suite robustness --shard K/N` and a worker's suite job with
//! a shard run the same block of whole initial states at level 0 and at
//! every level of the suite ([`evaluate_suite_shard`]); `d3il merge` joins
//! the parts with `d3il_metrics::suite_shard::merge_suite` (each level's
//! parts through the plain evaluation's merge, then the document as an
//! unsharded run builds it: the merged document is the unsharded one bit for
//! bit), which the server's sharded suite jobs use too.

use crate::eval::{evaluate, EvalError, EvalOptions, EvalRun, PolicyInfo};
use crate::perturb::Suite;
use crate::robustness::{suite_levels, SuiteObserver, SuitePlan};
use crate::shard::Shard;
use crate::tasks::LoadedTask;
use d3il_metrics::suite_shard::{check_parts, merge_suite as merge_suite_levels};
use d3il_policy::Policy;
use d3il_protocol::robustness::{RobustnessPart, RobustnessResult, ROBUSTNESS_PART_FORMAT};

/// Why robustness parts cannot be merged; each names the file and the fix.
pub use d3il_metrics::suite_shard::SuiteMergeError;

/// Level 0 and every level of `plan` on shard `shard`'s initial states.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_suite_shard(
    task: &LoadedTask,
    policy: &mut dyn Policy,
    info: &PolicyInfo,
    opts: &EvalOptions,
    suite: &Suite,
    plan: &SuitePlan,
    shard: Shard,
    observer: &mut dyn SuiteObserver,
) -> Result<RobustnessPart, EvalError> {
    observer.level_started(None);
    let mut counts = |d, n| observer.progress(d, n);
    let run = EvalRun::shard(shard).counting(&mut counts);
    let (control, t) = evaluate(task, policy, info, opts, run)?;
    observer.level_finished(&t);
    let mut levels = Vec::with_capacity(plan.levels.len());
    for p in &plan.levels {
        observer.level_started(Some(p));
        let mut counts = |d, n| observer.progress(d, n);
        let run = EvalRun::shard(shard).perturbed(p).counting(&mut counts);
        let (part, t) = evaluate(task, policy, info, opts, run)?;
        observer.level_finished(&t);
        levels.push(part);
    }
    Ok(RobustnessPart {
        format: ROBUSTNESS_PART_FORMAT.into(),
        task: suite.file.task,
        suite: suite.name.clone(),
        suite_sha256: suite.sha256.clone(),
        shard,
        control,
        levels,
    })
}

/// What a robustness run gives: the document, or with a shard its part.
pub enum SuiteRun {
    Whole(Box<RobustnessResult>),
    Part(Box<RobustnessPart>),
}

/// The whole suite ([`crate::robustness::evaluate_suite`]) or, with `shard`,
/// its block of states ([`evaluate_suite_shard`]): what a worker's suite job
/// and `d3il eval --suite` run.
#[allow(clippy::too_many_arguments)]
pub fn evaluate_suite_or_shard(
    task: &LoadedTask,
    policy: &mut dyn Policy,
    info: &PolicyInfo,
    opts: &EvalOptions,
    suite: &Suite,
    plan: &SuitePlan,
    shard: Option<Shard>,
    observer: &mut dyn SuiteObserver,
) -> Result<SuiteRun, EvalError> {
    Ok(match shard {
        Some(shard) => SuiteRun::Part(Box::new(evaluate_suite_shard(
            task, policy, info, opts, suite, plan, shard, observer,
        )?)),
        None => SuiteRun::Whole(Box::new(crate::robustness::evaluate_suite(
            task, policy, info, opts, suite, plan, observer,
        )?)),
    })
}

/// Joins the parts (`(file name, part)`, any order) of one sharded
/// robustness evaluation into its document, with the levels of this
/// build's suite file of the parts' name, whose sha256 must be theirs.
pub fn merge_suite(
    parts: Vec<(String, RobustnessPart)>,
) -> Result<RobustnessResult, SuiteMergeError> {
    check_parts(&parts)?;
    let first = &parts[0].1;
    let suite = Suite::named(first.task, &first.suite)
        .map_err(|e| SuiteMergeError::Suite(e.to_string()))?;
    if suite.sha256 != first.suite_sha256 {
        return Err(SuiteMergeError::Suite(format!(
            "the parts were made with suite {} of sha256 {}, this build's has sha256 {}",
            first.suite, first.suite_sha256, suite.sha256
        )));
    }
    merge_suite_levels(parts, &suite_levels(&suite))
}
