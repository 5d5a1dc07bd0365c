//! Reading, validating and accepting a submission (shared by the JSON API and
//! the HTML submit form). Every error names the offending field.

mod fields;
mod suite;
mod upload;

use crate::error::AppError;
use crate::queue::JobRunner;
pub use crate::quota::suite_evaluations;
use crate::state::AppState;
use crate::store::{NewMethod, NewPolicy, NewSubmission, SeedKey, Submitter};
use axum::http::{header, HeaderMap};
use d3il_protocol::{
    EndpointSecret, ErrorKind, Evaluated, Job, JobKind, Limits, ObsType, PolicyManifest,
    PolicySource, ProtocolKind, SuiteName, TaskId,
};
use fields::{
    fraction_field, manifest_field, method_fields, opt, policy_fields, protocol_field, seed_field,
    task_fields,
};
use std::sync::Arc;
pub use suite::check_suite_available;
use suite::suite_field;
pub use upload::{
    disk_quota_error, read_multipart, Caller, Quota, RawSubmission, UploadedFile, TEXT_FIELDS,
};

/// Refuses a body whose declared length is over the limit before reading any
/// of it (oversized uploads refused before they are buffered).
pub fn check_declared_length(headers: &HeaderMap, max: usize) -> Result<(), AppError> {
    if let Some(len) = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
    {
        // The limit is on the file; allow 1 MiB for the form fields around it.
        if len > (max + (1 << 20)) as u64 {
            return Err(too_large(max));
        }
    }
    Ok(())
}

fn too_large(max: usize) -> AppError {
    AppError::PayloadTooLarge(format!(
        "the request is larger than the upload limit of {} MiB; shrink the ONNX file (e.g. strip training-only nodes) or ask the operator to raise --max-upload-mb",
        max >> 20
    ))
}

/// A submission that passed validation.
#[derive(Debug)]
pub struct ValidSubmission {
    pub method: NewMethod,
    pub task: TaskId,
    pub obs_type: ObsType,
    pub training_seed: i64,
    pub data_fraction: f64,
    pub protocol: ProtocolKind,
    pub manifest: PolicyManifest,
    pub policy: ValidPolicy,
    /// The perturbation suite asked for.
    pub suite: Option<SuiteName>,
}

#[derive(Debug)]
pub enum ValidPolicy {
    /// The streamed upload, still under its temporary name.
    Onnx(UploadedFile),
    /// An endpoint's URL and the shared secret the evaluator sends it, if any.
    Remote(String, Option<EndpointSecret>),
}

/// Validates every field; the first problem is reported with its field name.
/// The upload (if any) moves into the result; on an error it is dropped,
/// which deletes its file.
pub fn validate(mut raw: RawSubmission, limits: &Limits) -> Result<ValidSubmission, AppError> {
    let raw_ref = &raw;
    let method = method_fields(raw_ref)?;
    let (task, obs_type) = task_fields(raw_ref)?;
    let training_seed = seed_field(raw_ref)?;
    let data_fraction = fraction_field(raw_ref)?;
    let protocol = protocol_field(raw_ref)?;
    let manifest = manifest_field(raw_ref, task, obs_type, method.history)?;
    let suite = suite_field(raw_ref)?;
    let policy = policy_fields(&mut raw, limits)?;
    Ok(ValidSubmission {
        suite,
        method,
        task,
        obs_type,
        training_seed,
        data_fraction,
        protocol,
        manifest,
        policy,
    })
}

/// The checks that need no file, run on the fields sent before the `onnx`
/// part and before any of it is read: a field that is there must be valid,
/// the method must not belong to someone else, the seed must be free, and
/// the submitter must have disk quota left. Returns the upload's quota.
pub async fn precheck(
    state: &AppState,
    raw: &RawSubmission,
    who: &Submitter,
) -> Result<Quota, AppError> {
    // A submitter out of quota is refused before any of the file is read
    // (a suite by its evaluations when the fields say which).
    let (cost, what) = match (opt(raw, "suite"), task_fields(raw)) {
        (Some(_), Ok((task, obs))) => work_of(state, true, task, obs),
        _ => (1, "a plain evaluation".to_string()),
    };
    crate::quota::admit(state, who, cost, &what).await?;
    if opt(raw, "endpoint_url").is_some() {
        return Err(AppError::invalid(
            "endpoint_url",
            "give either an `onnx` file or an `endpoint_url`, not both",
        ));
    }
    let has = |k: &str| opt(raw, k).is_some();
    let method = if has("method") {
        Some(method_fields(raw)?)
    } else {
        None
    };
    let task = if has("task") {
        let (task, obs_type) = task_fields(raw)?;
        if has("manifest") {
            manifest_field(raw, task, obs_type, method.as_ref().and_then(|m| m.history))?;
        }
        Some((task, obs_type))
    } else {
        None
    };
    let seed = if has("training_seed") {
        Some(seed_field(raw)?)
    } else {
        None
    };
    let fraction = fraction_field(raw)?;
    let protocol = protocol_field(raw)?;
    if let Some(m) = &method {
        let key = match (task, seed) {
            (Some((task, obs_type)), Some(training_seed)) => Some((task, obs_type, training_seed)),
            _ => None,
        };
        check_owner_and_seed(state, &m.name, who, key, fraction, protocol).await?;
    }
    let quota = Quota {
        max_upload: state.cfg.max_upload_bytes,
        disk_used: state.store.submitter_disk_bytes(who.id).await?,
        disk_cap: state.cfg.max_disk_bytes_per_submitter,
    };
    if let Some(cap) = quota.disk_cap {
        if quota.disk_used >= cap {
            return Err(disk_quota_error(quota.disk_used, cap));
        }
    }
    Ok(quota)
}

/// A method that exists must be the caller's; with the seed's key known,
/// the seed must be free (`create_submission` checks again under the lock).
async fn check_owner_and_seed(
    state: &AppState,
    method: &str,
    who: &Submitter,
    key: Option<(TaskId, ObsType, i64)>,
    data_fraction: f64,
    protocol: ProtocolKind,
) -> Result<(), AppError> {
    let Some(existing) = state.store.method_by_name(method).await? else {
        return Ok(());
    };
    if existing.submitter_id.is_some() && existing.submitter_id != Some(who.id) {
        return Err(AppError::Conflict {
            field: Some("method".into()),
            message: format!(
                "method `{method}` belongs to another submitter; choose a different name"
            ),
        });
    }
    if let Some((task, obs_type, training_seed)) = key {
        state
            .store
            .check_seed_free(&SeedKey {
                method_id: existing.id,
                task,
                obs_type,
                data_fraction,
                protocol,
                training_seed,
            })
            .await?;
    }
    Ok(())
}

/// Env steps per rollout of an uploaded model's dry run (at least two policy
/// calls whatever the manifest's `execute`).
pub const DRY_RUN_MIN_STEPS: usize = 16;

/// Runs a submission's policy through a short sandboxed quick-protocol
/// evaluation before it is queued; any failure is reported to the submitter
/// and nothing is stored. A remote endpoint runs the whole quick protocol (its
/// conformance dry-run); an uploaded model runs it with every rollout cut
/// after a few steps, which loads it, feeds it real observations at batch
/// ≥ 2 and checks its actions, so a graph that cannot run is refused here,
/// never at rollout 0 of its evaluation. Returns whether the evaluation
/// simulates each initial state once (a deterministic policy: the result
/// manifest's `simulated_once`), which queue estimates use.
pub async fn dry_run(
    runner: Arc<dyn JobRunner>,
    state: &AppState,
    v: &ValidSubmission,
    policy: PolicySource,
) -> Result<bool, AppError> {
    let mut limits = state.cfg.limits.clone();
    limits.wall_seconds = limits.wall_seconds.min(120);
    let remote = matches!(policy, PolicySource::Remote { .. });
    let job = Job {
        kind: JobKind::of(v.suite, None),
        job_id: "dry-run".into(),
        task: v.task,
        protocol: ProtocolKind::Quick,
        policy,
        manifest: v.manifest.clone(),
        seed: 0,
        limits,
        assets_dir: state.cfg.assets_dir.to_string_lossy().into_owned(),
        dry_run_steps: (!remote).then(|| (2 * v.manifest.execute).max(DRY_RUN_MIN_STEPS)),
        build: None,
    };
    let report = tokio::task::spawn_blocking(move || runner.run(&job, &mut |_, _| {}))
        .await
        .map_err(|e| AppError::Internal(format!("dry-run panicked: {e}")))?;
    let e = match report.outcome {
        Ok(Evaluated::Result(r)) => return Ok(r.manifest.simulated_once),
        Ok(Evaluated::Part(p)) => return Ok(p.manifest.simulated_once),
        Ok(Evaluated::Robustness(d)) => return Ok(d.control.manifest.simulated_once),
        Ok(Evaluated::SuitePart(p)) => return Ok(p.control.manifest.simulated_once),
        Ok(Evaluated::Race(_)) => {
            return Err(AppError::Internal(
                "a dry-run answered with a race report".into(),
            ))
        }
        Err(e) if e.kind == ErrorKind::Internal => return Err(AppError::Internal(e.message)),
        Err(e) => e,
    };
    let kind = serde_json::to_value(e.kind)
        .ok()
        .and_then(|v| v.as_str().map(str::to_string))
        .unwrap_or_default();
    Err(if remote {
        AppError::EndpointRejected {
            kind,
            message: format!(
                "the endpoint failed the conformance dry-run (docs/remote-protocol.md): {}",
                e.message
            ),
        }
    } else {
        AppError::invalid(
            "onnx",
            format!(
                "the model failed its dry run in the sandbox ({kind}): {}; check it with `d3il eval --protocol quick` (docs/export.md)",
                e.message
            ),
        )
    })
}

/// What a submission costs the quota, in evaluations, and how a refusal
/// names it.
fn work_of(state: &AppState, suite: bool, task: TaskId, obs: ObsType) -> (i64, String) {
    let n = crate::quota::submission_evaluations(&state.cfg.assets_dir, task, obs, suite);
    if suite {
        (
            n,
            format!(
                "the robustness suite of {} ({} observations: level 0 and {} levels)",
                task.slug(),
                obs.as_str(),
                n - 1
            ),
        )
    } else {
        (1, "a plain evaluation".to_string())
    }
}

/// Stores a validated submission and queues its job; returns the submission id
/// once it is durable.
pub async fn accept(
    state: &AppState,
    mut v: ValidSubmission,
    who: &Submitter,
) -> Result<i64, AppError> {
    let store = &state.store;
    let (cost, what) = work_of(state, v.suite.is_some(), v.task, v.obs_type);
    crate::quota::admit(state, who, cost, &what).await?;
    // A duplicate seed is refused before an endpoint's dry-run (which can
    // take minutes) or an ONNX write; create_submission checks again under
    // the write lock. A new method cannot hold the seed yet.
    check_owner_and_seed(
        state,
        &v.method.name,
        who,
        Some((v.task, v.obs_type, v.training_seed)),
        v.data_fraction,
        v.protocol,
    )
    .await?;
    if v.suite.is_some() {
        check_suite_available(&state.cfg.assets_dir, v.task, v.obs_type)?;
    }
    let dry = match &v.policy {
        ValidPolicy::Remote(url, secret) => Some(PolicySource::Remote {
            url: url.clone(),
            secret: secret.clone(),
        }),
        ValidPolicy::Onnx(_) if !state.cfg.dry_run_uploads => None,
        ValidPolicy::Onnx(file) => Some(PolicySource::Onnx {
            path: file
                .path()
                .ok_or_else(|| AppError::Internal("the upload was already stored".into()))?
                .to_string_lossy()
                .into_owned(),
            sha256: file.sha256.clone(),
        }),
    };
    let dry_once = match dry {
        Some(policy) => Some(dry_run(state.runner.clone(), state, &v, policy).await?),
        None => None,
    };
    // Only an accepted submission creates its method (a refused dry-run
    // leaves nothing behind).
    let method = store.ensure_method(&v.method, Some(who.id)).await?;
    // The upload becomes `<sha256>.onnx`; `created` when this request wrote
    // it (so a refused insert deletes it again).
    let mut created = None;
    // No failed submission's file release may run between placing the file
    // and recording the submission that refers to it.
    let files = store.lock_policy_files().await?;
    // Again under the lock: concurrent submissions of one submitter (on
    // this host) are counted one after the other.
    crate::quota::admit(state, who, cost, &what).await?;
    let policy = match &mut v.policy {
        ValidPolicy::Onnx(file) => {
            if let Some(cap) = state.cfg.max_disk_bytes_per_submitter {
                // Concurrent uploads of one submitter are counted here.
                let used = store.submitter_disk_bytes(who.id).await?;
                if used + file.bytes > cap {
                    return Err(disk_quota_error(used, cap));
                }
            }
            let tmp = file
                .path()
                .ok_or_else(|| AppError::Internal("the upload was already stored".into()))?
                .to_path_buf();
            let (path, new) = store.commit_onnx(&tmp, &file.sha256).await?;
            file.take_path();
            if new {
                created = Some(path.to_string_lossy().into_owned());
            }
            NewPolicy::Onnx {
                sha256: file.sha256.clone(),
                bytes: file.bytes as i64,
                path,
            }
        }
        ValidPolicy::Remote(url, secret) => NewPolicy::Remote {
            url: url.clone(),
            secret: secret.clone(),
        },
    };
    let manifest_json = serde_json::to_string(&v.manifest)
        .map_err(|e| AppError::Internal(format!("manifest encoding: {e}")))?;
    // Jobs are split into `--shards` shards of whole initial states (never
    // more than the protocol has), run by any worker slot or host.
    let shards = state
        .cfg
        .shards
        .min(v.task.protocol_size(v.protocol, usize::MAX).0);
    let new = NewSubmission {
        method_id: method.id,
        submitter_id: Some(who.id),
        task: v.task,
        obs_type: v.obs_type,
        training_seed: v.training_seed,
        data_fraction: v.data_fraction,
        protocol: v.protocol,
        policy,
        manifest_json,
        simulated_once: dry_once,
    };
    // A suite's job is sharded by the same rule: each shard runs level 0
    // and every level on its block of initial states.
    let inserted = match v.suite {
        Some(suite) => {
            store
                .create_suite_submission(&new, state.cfg.max_attempts, suite.as_str(), shards)
                .await
        }
        None => {
            store
                .create_submission_sharded(&new, state.cfg.max_attempts, shards)
                .await
        }
    };
    drop(files);
    let id = match inserted {
        Ok(id) => id,
        Err(e) => {
            if let Some(path) = created {
                if let Err(e) = store.release_policy_file(&path).await {
                    tracing::warn!("refused upload {path} not deleted: {e}");
                }
            }
            return Err(e.into());
        }
    };
    state.signal.job_queued();
    tracing::info!("submission {id} accepted from `{}`", who.name);
    Ok(id)
}
