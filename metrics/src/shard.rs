//! Sharded evaluations (docs/cluster.md): shard K of N evaluates a
//! contiguous block of whole initial states, the evaluator's `evaluate` of one shard
//! writes it as an [`EvalPart`], and [`merge`] joins the N parts into the
//! [`EvalResult`] a plain evaluation gives, bit for bit (every metric and
//! rollout record; only the measured inference time differs). Rollout ids,
//! and with them the policy noise keyed by (seed, rollout, step), are global.
//!
//! Here, in the metrics crate, because records become a result in one place
//! ([`assemble`]) for a plain evaluation, the CLI's `d3il merge` and the
//! server merging the shards its worker hosts ran.

use crate::{Bootstrap, MetricsError, Outcome};
use d3il_protocol::{EvalResult, FailureReason, ProtocolManifest, RolloutRecord};

pub use d3il_protocol::shard::{EvalPart, Shard, ShardError, PART_FORMAT};

/// Why parts cannot be merged; each names the files and what to do.
#[derive(Debug, thiserror::Error)]
pub enum MergeError {
    #[error("no part files given: pass the files `d3il eval --shard K/N --json FILE` wrote")]
    NoParts,
    #[error(
        "{file} is not a part file of this version (format `{found}`, expected `{PART_FORMAT}`)"
    )]
    Format { file: String, found: String },
    #[error(
        "{a} and {b} come from different {what}: {field} is {values}; \
         merge only the parts of one evaluation"
    )]
    Mismatch {
        what: &'static str,
        field: String,
        a: String,
        b: String,
        /// "`x` in a but `y` in b".
        values: String,
    },
    #[error("{a} is shard {sa} but {b} is shard {sb}: all parts must split the evaluation into the same number of shards")]
    ShardCount {
        a: String,
        b: String,
        sa: Shard,
        sb: Shard,
    },
    #[error("shard {shard} is given twice ({a} and {b}); pass each shard once")]
    Duplicate { shard: Shard, a: String, b: String },
    #[error(
        "missing {missing}: run `d3il eval ... --shard K/N` for them and merge all {count} parts"
    )]
    Missing { missing: String, count: usize },
    #[error("{file} is inconsistent ({why}); rerun its shard")]
    Inconsistent { file: String, why: String },
    #[error(transparent)]
    Metrics(#[from] MetricsError),
}

/// Which evaluation a manifest field identifies, for the mismatch message.
fn field_kind(field: &str) -> &'static str {
    match field {
        "policy_sha256" | "history" | "horizon" | "execute" | "obs_type" => "policies",
        "initial_states" | "initial_states_sha256" => "initial-state sets",
        "robot_look" => {
            "robot looks (only some hosts have the converted Panda meshes; ./dev installs them)"
        }
        "task" | "task_version" | "mjcf_sha256" => "tasks",
        "evaluator_version" | "mujoco_version" => "evaluator builds",
        _ => "protocols",
    }
}

fn check_part(file: &str, p: &EvalPart) -> Result<(), MergeError> {
    let bad = |why: String| MergeError::Inconsistent {
        file: file.to_string(),
        why,
    };
    let range = p
        .shard
        .contexts(p.manifest.n_contexts)
        .map_err(|e| bad(e.to_string()))?;
    if p.contexts != [range.start, range.end] {
        return Err(bad(format!(
            "shard {} of {} initial states covers {range:?}, the file says {:?}",
            p.shard, p.manifest.n_contexts, p.contexts
        )));
    }
    let per = p.manifest.rollouts_per_context;
    if p.rollouts.len() != range.len() * per || p.behaviour_keys.len() != p.rollouts.len() {
        return Err(bad(format!(
            "{} records and {} behaviour keys for {} initial states x {per} rollouts",
            p.rollouts.len(),
            p.behaviour_keys.len(),
            range.len()
        )));
    }
    for (i, r) in p.rollouts.iter().enumerate() {
        let want = (range.start + i / per, i % per);
        if (r.context_index, r.rollout_index) != want {
            return Err(bad(format!(
                "record {i} is rollout {} of initial state {}, expected rollout {} of {}",
                r.rollout_index, r.context_index, want.1, want.0
            )));
        }
    }
    Ok(())
}

/// Joins the parts of one sharded evaluation (`(file name, part)`, any order)
/// into its result, computed by the same [`assemble`] as a plain evaluation.
/// Refuses parts of different policies, protocols or initial-state sets,
/// missing and duplicate shards.
pub fn merge(parts: Vec<(String, EvalPart)>) -> Result<EvalResult, MergeError> {
    let Some((first_file, first)) = parts.first() else {
        return Err(MergeError::NoParts);
    };
    let first_manifest =
        serde_json::to_value(&first.manifest).map_err(|e| MergeError::Inconsistent {
            file: first_file.clone(),
            why: e.to_string(),
        })?;
    for (file, p) in &parts {
        if p.format != PART_FORMAT {
            return Err(MergeError::Format {
                file: file.clone(),
                found: p.format.clone(),
            });
        }
        check_part(file, p)?;
        let m = serde_json::to_value(&p.manifest).map_err(|e| MergeError::Inconsistent {
            file: file.clone(),
            why: e.to_string(),
        })?;
        if let (Some(a), Some(b)) = (first_manifest.as_object(), m.as_object()) {
            // Policy first: the likeliest mistake and the most useful message;
            // then the robot look, which also changes the scene's hash.
            let mut fields: Vec<&String> = a.keys().chain(b.keys()).collect();
            fields.sort_by_key(|f| {
                let rank = match field_kind(f) {
                    "policies" => 0,
                    _ if f.as_str() == "robot_look" => 1,
                    _ => 2,
                };
                (rank, f.as_str())
            });
            fields.dedup();
            for f in fields {
                let (va, vb) = (a.get(f), b.get(f));
                if va != vb {
                    let show = |v: Option<&serde_json::Value>| match v {
                        Some(serde_json::Value::String(s)) => s.clone(),
                        Some(v) => v.to_string(),
                        None => "absent".into(),
                    };
                    return Err(MergeError::Mismatch {
                        what: field_kind(f),
                        field: f.clone(),
                        a: first_file.clone(),
                        b: file.clone(),
                        values: format!(
                            "`{}` in {first_file} but `{}` in {file}",
                            show(va),
                            show(vb)
                        ),
                    });
                }
            }
        }
        if p.bootstrap_resamples != first.bootstrap_resamples {
            return Err(MergeError::Mismatch {
                what: "protocols",
                field: "bootstrap_resamples".into(),
                a: first_file.clone(),
                b: file.clone(),
                values: format!(
                    "{} in {first_file} but {} in {file}",
                    first.bootstrap_resamples, p.bootstrap_resamples
                ),
            });
        }
        if p.shard.count != first.shard.count {
            return Err(MergeError::ShardCount {
                a: first_file.clone(),
                b: file.clone(),
                sa: first.shard,
                sb: p.shard,
            });
        }
    }
    let count = first.shard.count;
    let mut slots: Vec<Option<(String, EvalPart)>> = vec![None; count];
    for (file, p) in parts {
        let slot = &mut slots[p.shard.index - 1];
        if let Some((a, _)) = slot {
            return Err(MergeError::Duplicate {
                shard: p.shard,
                a: a.clone(),
                b: file,
            });
        }
        *slot = Some((file, p));
    }
    let missing: Vec<String> = slots
        .iter()
        .enumerate()
        .filter(|(_, s)| s.is_none())
        .map(|(i, _)| format!("{}/{count}", i + 1))
        .collect();
    if !missing.is_empty() {
        return Err(MergeError::Missing {
            missing: format!(
                "shard{} {}",
                if missing.len() > 1 { "s" } else { "" },
                missing.join(", ")
            ),
            count,
        });
    }
    let mut manifest = None;
    let mut rollouts = Vec::new();
    let mut keys = Vec::new();
    let (mut policy_s, mut calls, mut resamples) = (0.0, 0, 0);
    for (_, p) in slots.into_iter().flatten() {
        policy_s += p.policy_seconds;
        calls += p.policy_calls;
        resamples = p.bootstrap_resamples;
        rollouts.extend(p.rollouts);
        keys.extend(p.behaviour_keys);
        manifest.get_or_insert(p.manifest);
    }
    let manifest = manifest.ok_or(MergeError::NoParts)?;
    Ok(assemble(
        manifest,
        rollouts,
        &keys,
        inference_ms(policy_s, calls),
        resamples,
    )?)
}

/// Mean wall-clock milliseconds per batched policy call.
pub fn inference_ms(policy_s: f64, policy_calls: usize) -> f64 {
    if policy_calls > 0 {
        1000.0 * policy_s / policy_calls as f64
    } else {
        0.0
    }
}

/// The one place where rollout records become an [`EvalResult`]: the D3IL
/// metrics (bootstrap seeded by the manifest's seed), the per-context
/// breakdown and the unstable-rollout count. `behaviour_keys[i]` is the
/// metrics' behaviour key of `rollouts[i]` ([`crate::Outcome::behaviour`]).
/// Used by the evaluator's `evaluate` and by [`merge`].
pub fn assemble(
    manifest: ProtocolManifest,
    rollouts: Vec<RolloutRecord>,
    behaviour_keys: &[Option<String>],
    inference_ms: f64,
    bootstrap_resamples: usize,
) -> Result<EvalResult, MetricsError> {
    if behaviour_keys.len() != rollouts.len() {
        return Err(MetricsError::Records(format!(
            "{} rollout records but {} behaviour keys",
            rollouts.len(),
            behaviour_keys.len()
        )));
    }
    let outcomes: Vec<Outcome> = rollouts
        .iter()
        .zip(behaviour_keys)
        .map(|(r, key)| Outcome {
            context_index: r.context_index,
            success: r.success,
            behaviour: key.clone(),
        })
        .collect();
    let rollouts_ended_unstable = rollouts
        .iter()
        .filter(|r| {
            r.failure
                .as_ref()
                .is_some_and(|f| f.reason == FailureReason::SimUnstable)
        })
        .count();
    let evaluation = crate::evaluate(
        manifest.task,
        &outcomes,
        inference_ms,
        &Bootstrap {
            resamples: bootstrap_resamples,
            confidence: 0.95,
            seed: manifest.seed,
        },
    )?;
    Ok(EvalResult {
        manifest,
        metrics: evaluation.metrics,
        per_context: evaluation.per_context,
        rollouts,
        rollouts_ended_unstable,
    })
}
