//! A robustness evaluation in shards (issue 40, item 5; docs/robustness.md):
//! `d3il eval --suite robustness --shard K/N` runs the same block of whole
//! initial states at level 0 and at every level of the suite
//! ([`evaluate_suite_shard`]); `d3il merge` joins each level's parts with
//! [`crate::shard::merge`], the plain evaluation's merge, and builds the
//! document with [`crate::robustness::document`], as an unsharded run does:
//! the merged document is the unsharded one bit for bit.

use crate::eval::{evaluate_perturbed_shard, evaluate_shard, EvalError, EvalOptions, PolicyInfo};
use crate::perturb::Suite;
use crate::robustness::{document, SuiteObserver, SuitePlan};
use crate::shard::{merge, MergeError, Shard};
use crate::tasks::LoadedTask;
use d3il_policy::Policy;
use d3il_protocol::perturbation::Perturbation;
use d3il_protocol::robustness::{RobustnessPart, RobustnessResult, ROBUSTNESS_PART_FORMAT};
use d3il_protocol::shard::EvalPart;

/// Why robustness parts cannot be merged; each names the file and the fix.
#[derive(Debug, thiserror::Error)]
pub enum SuiteMergeError {
    #[error("{file} is not a part file of `d3il eval --suite robustness --shard K/N` (format `{found}`, expected `{ROBUSTNESS_PART_FORMAT}`)")]
    Format { file: String, found: String },
    #[error("{a} and {b} come from different robustness evaluations: {what}; merge only the parts of one evaluation")]
    Mismatch { a: String, b: String, what: String },
    #[error("{file}: {why}; rerun its shard")]
    Inconsistent { file: String, why: String },
    #[error("{level}: {source}")]
    Level {
        level: String,
        #[source]
        source: Box<MergeError>,
    },
    #[error(transparent)]
    Eval(#[from] EvalError),
}

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
    let (control, t) = evaluate_shard(task, policy, info, opts, shard, &mut |d, n| {
        observer.progress(d, n)
    })?;
    observer.level_finished(&t);
    let mut levels = Vec::with_capacity(plan.levels.len());
    for p in &plan.levels {
        observer.level_started(Some(p));
        let (part, t) =
            evaluate_perturbed_shard(task, policy, info, opts, p, shard, &mut |d, n| {
                observer.progress(d, n)
            })?;
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

/// Joins the parts (`(file name, part)`, any order) of one sharded
/// robustness evaluation into its document.
pub fn merge_suite(
    parts: Vec<(String, RobustnessPart)>,
) -> Result<RobustnessResult, SuiteMergeError> {
    let Some((first_file, first)) = parts.first() else {
        return Err(SuiteMergeError::Level {
            level: "level 0".into(),
            source: Box::new(MergeError::NoParts),
        });
    };
    let (first_file, task, suite_name, sha) = (
        first_file.clone(),
        first.task,
        first.suite.clone(),
        first.suite_sha256.clone(),
    );
    for (file, p) in &parts {
        if p.format != ROBUSTNESS_PART_FORMAT {
            return Err(SuiteMergeError::Format {
                file: file.clone(),
                found: p.format.clone(),
            });
        }
        let ours = (p.task, p.suite.as_str(), p.suite_sha256.as_str());
        if ours != (task, suite_name.as_str(), sha.as_str()) {
            return Err(SuiteMergeError::Mismatch {
                a: first_file.clone(),
                b: file.clone(),
                what: format!(
                    "task {task}, suite {suite_name} (sha256 {sha}) in {first_file} but task {}, suite {} (sha256 {}) in {file}",
                    p.task, p.suite, p.suite_sha256
                ),
            });
        }
        if let Some(bad) = std::iter::once(&p.control)
            .chain(&p.levels)
            .find(|l| l.shard != p.shard)
        {
            return Err(SuiteMergeError::Inconsistent {
                file: file.clone(),
                why: format!("shard {} holds a level of shard {}", p.shard, bad.shard),
            });
        }
    }
    let suite = Suite::named(task, &suite_name).map_err(|e| EvalError::Setup(e.to_string()))?;
    if suite.sha256 != sha {
        return Err(EvalError::Setup(format!(
            "the parts were made with suite {suite_name} of sha256 {sha}, this build's has sha256 {}",
            suite.sha256
        ))
        .into());
    }
    let expected = suite.perturbations();
    for (file, p) in &parts {
        if p.levels.len() != expected.len() {
            return Err(SuiteMergeError::Inconsistent {
                file: file.clone(),
                why: format!(
                    "it has {} levels, suite {suite_name} has {}",
                    p.levels.len(),
                    expected.len()
                ),
            });
        }
    }
    // Level by level: the parts of every shard, in the files' order.
    let mut controls: Vec<(String, EvalPart)> = Vec::with_capacity(parts.len());
    let mut levels: Vec<Vec<(String, EvalPart)>> = vec![Vec::new(); expected.len()];
    for (file, p) in parts {
        controls.push((file.clone(), p.control));
        for (i, l) in p.levels.into_iter().enumerate() {
            levels[i].push((file.clone(), l));
        }
    }
    let control = merge(controls).map_err(|source| SuiteMergeError::Level {
        level: "level 0".into(),
        source: Box::new(source),
    })?;
    let mut results: Vec<(Perturbation, d3il_protocol::EvalResult)> = vec![];
    for (p, level) in expected.into_iter().zip(levels) {
        let name = format!("level {}/{}", p.axis, p.level);
        let r = merge(level).map_err(|source| SuiteMergeError::Level {
            level: name.clone(),
            source: Box::new(source),
        })?;
        if r.manifest.perturbation.as_ref() != Some(&p) {
            return Err(SuiteMergeError::Inconsistent {
                file: first_file.clone(),
                why: format!("its {name} is not that level of suite {suite_name}"),
            });
        }
        results.push((p, r));
    }
    Ok(document(&suite, control, results)?)
}
