//! A robustness evaluation's document (docs/robustness.md) from
//! level 0 and every level's results ([`document`]), and the merge of a
//! sharded robustness evaluation's parts into it ([`merge_suite`]): each
//! level's parts through [`crate::shard::merge`], the plain evaluation's
//! merge, then the same [`document`] as an unsharded run, so the merged
//! document is the unsharded one bit for bit. `d3il eval --suite`, `d3il
//! merge` (through the evaluator, which checks the suite file too) and the
//! server's sharded suite jobs all end here.

use crate::robustness::robustness_scores;
use crate::shard::{merge, MergeError};
use crate::{Bootstrap, MetricsError};
use d3il_protocol::perturbation::{Axis, Perturbation};
use d3il_protocol::robustness::{
    AxisScore, LevelResult, RobustnessPart, RobustnessResult, ROBUSTNESS_FORMAT,
    ROBUSTNESS_PART_FORMAT,
};
use d3il_protocol::shard::EvalPart;
use d3il_protocol::{Comparison, ContextResult, EvalResult};

/// Resamples of the paired comparisons and of the scores' intervals (as
/// `d3il compare`'s default).
pub const RESAMPLES: usize = 2000;

/// What a robustness document needs to know of its suite: the file's name
/// and sha256, its axes and its levels, in the suite's order.
#[derive(Debug, Clone, PartialEq)]
pub struct SuiteLevels {
    pub name: String,
    pub sha256: String,
    pub axes: Vec<Axis>,
    pub levels: Vec<Perturbation>,
}

impl SuiteLevels {
    /// The suite's levels as a part ran them (each level's manifest records
    /// its perturbation), the axes in the order they first appear. For a
    /// caller without the suite file (the server: the worker checked the
    /// file's sha256); [`merge_suite`] then checks that every part ran the
    /// same levels.
    pub fn of_part(file: &str, part: &RobustnessPart) -> Result<SuiteLevels, SuiteMergeError> {
        let mut axes: Vec<Axis> = vec![];
        let mut levels = Vec::with_capacity(part.levels.len());
        for (i, l) in part.levels.iter().enumerate() {
            let Some(p) = &l.manifest.perturbation else {
                return Err(SuiteMergeError::Inconsistent {
                    file: file.into(),
                    why: format!("its level {} records no perturbation", i + 1),
                });
            };
            if !axes.contains(&p.axis) {
                axes.push(p.axis);
            }
            levels.push(p.clone());
        }
        Ok(SuiteLevels {
            name: part.suite.clone(),
            sha256: part.suite_sha256.clone(),
            axes,
            levels,
        })
    }
}

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
    /// The parts' suite is not this build's (named by the evaluator's check).
    #[error("{0}")]
    Suite(String),
    #[error("metrics: {0}")]
    Metrics(#[from] MetricsError),
}

/// The checks that need no suite file: every part has the part format,
/// the same task and suite (name and sha256), and levels of its own shard.
pub fn check_parts(parts: &[(String, RobustnessPart)]) -> Result<(), SuiteMergeError> {
    let Some((first_file, first)) = parts.first() else {
        return Err(SuiteMergeError::Level {
            level: "level 0".into(),
            source: Box::new(MergeError::NoParts),
        });
    };
    let (task, suite_name, sha) = (first.task, &first.suite, &first.suite_sha256);
    for (file, p) in parts {
        if p.format != ROBUSTNESS_PART_FORMAT {
            return Err(SuiteMergeError::Format {
                file: file.clone(),
                found: p.format.clone(),
            });
        }
        if (p.task, &p.suite, &p.suite_sha256) != (task, suite_name, sha) {
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
    Ok(())
}

/// Joins the parts (`(file name, part)`, any order) of one sharded
/// robustness evaluation of `suite` into its document.
pub fn merge_suite(
    parts: Vec<(String, RobustnessPart)>,
    suite: &SuiteLevels,
) -> Result<RobustnessResult, SuiteMergeError> {
    check_parts(&parts)?;
    let first_file = parts[0].0.clone();
    let expected = &suite.levels;
    for (file, p) in &parts {
        if p.levels.len() != expected.len() {
            return Err(SuiteMergeError::Inconsistent {
                file: file.clone(),
                why: format!(
                    "it has {} levels, suite {} has {}",
                    p.levels.len(),
                    suite.name,
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
    let mut results: Vec<(Perturbation, EvalResult)> = vec![];
    for (p, level) in expected.iter().zip(levels) {
        let name = format!("level {}/{}", p.axis, p.level);
        let r = merge(level).map_err(|source| SuiteMergeError::Level {
            level: name.clone(),
            source: Box::new(source),
        })?;
        if r.manifest.perturbation.as_ref() != Some(p) {
            return Err(SuiteMergeError::Inconsistent {
                file: first_file.clone(),
                why: format!("its {name} is not that level of suite {}", suite.name),
            });
        }
        results.push((p.clone(), r));
    }
    let seed = control.manifest.seed;
    Ok(document(suite, control, results, seed)?)
}

/// The robustness document of level 0 (`control`) and the levels'
/// results (in the suite's order): each level's paired drop against level
/// 0 (`d3il compare`'s machinery, [`RESAMPLES`] resamples, seeded by
/// `seed`), the success retained and the scores per axis and overall.
pub fn document(
    suite: &SuiteLevels,
    control: EvalResult,
    results: Vec<(Perturbation, EvalResult)>,
    seed: u64,
) -> Result<RobustnessResult, MetricsError> {
    let cfg = Bootstrap {
        resamples: RESAMPLES,
        confidence: 0.95,
        seed,
    };
    let results = results
        .into_iter()
        .map(|(p, r)| {
            let paired = crate::compare(&control, &r, &cfg)?;
            Ok((p, r, paired))
        })
        .collect::<Result<Vec<(Perturbation, EvalResult, Comparison)>, MetricsError>>()?;
    let axes = &suite.axes;
    let indexed: Vec<(usize, &[ContextResult])> = results
        .iter()
        .map(|(p, r, _)| {
            let a = axes.iter().position(|&x| x == p.axis).unwrap_or(0);
            (a, &r.per_context[..])
        })
        .collect();
    let scores = robustness_scores(&control.per_context, &indexed, axes.len(), &cfg)?;
    Ok(RobustnessResult {
        format: ROBUSTNESS_FORMAT.into(),
        task: control.manifest.task,
        suite: suite.name.clone(),
        suite_sha256: suite.sha256.clone(),
        levels: results
            .into_iter()
            .zip(&scores.retained)
            .map(|((p, result, paired), retained)| LevelResult {
                axis: p.axis,
                level: p.level,
                setting: p.setting,
                result,
                paired,
                retained: *retained,
            })
            .collect(),
        axes: axes
            .iter()
            .zip(&scores.axes)
            .map(|(&axis, score)| AxisScore {
                axis,
                score: *score,
            })
            .collect(),
        overall: scores.overall,
        control,
        resamples: cfg.resamples,
        confidence: cfg.confidence,
    })
}
