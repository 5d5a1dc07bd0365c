//! Reading, validating and accepting a submission (shared by the JSON API and
//! the HTML submit form). Every error names the offending field.

mod suite;
mod upload;

use crate::error::AppError;
use crate::queue::JobRunner;
pub use crate::quota::suite_evaluations;
use crate::state::AppState;
use crate::store::{NewMethod, NewPolicy, NewSubmission, SeedKey, Submitter};
use axum::http::{header, HeaderMap};
use d3il_protocol::{
    EndpointSecret, ErrorKind, Evaluated, Job, Limits, ObsType, PolicyManifest, PolicySource,
    ProtocolKind, TaskId,
};
use std::str::FromStr;
use std::sync::Arc;
use suite::suite_field;
pub use suite::{check_suite_available, SUITE};
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
    /// The perturbation suite asked for (`robustness`).
    pub suite: Option<String>,
}

#[derive(Debug)]
pub enum ValidPolicy {
    /// The streamed upload, still under its temporary name.
    Onnx(UploadedFile),
    /// An endpoint's URL and the shared secret the evaluator sends it, if any.
    Remote(String, Option<EndpointSecret>),
}

fn opt(raw: &RawSubmission, k: &str) -> Option<String> {
    raw.text
        .get(k)
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty())
}

fn required(raw: &RawSubmission, k: &str, what: &str) -> Result<String, AppError> {
    opt(raw, k).ok_or_else(|| AppError::invalid(k, format!("`{k}` is required: {what}")))
}

fn check_url(field: &str, v: &str, schemes: &[&str]) -> Result<url::Url, AppError> {
    let u = url::Url::parse(v)
        .map_err(|e| AppError::invalid(field, format!("`{field}` is not a valid URL ({e})")))?;
    if !schemes.contains(&u.scheme()) {
        return Err(AppError::invalid(
            field,
            format!("`{field}` must use one of: {}", schemes.join(", ")),
        ));
    }
    if u.host_str().is_none() {
        return Err(AppError::invalid(field, format!("`{field}` has no host")));
    }
    Ok(u)
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

fn protocol_field(raw: &RawSubmission) -> Result<ProtocolKind, AppError> {
    match opt(raw, "protocol") {
        None => Ok(ProtocolKind::Paper),
        Some(p) => ProtocolKind::from_str(&p).map_err(|e| AppError::invalid("protocol", e)),
    }
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

/// The method's name and properties.
fn method_fields(raw: &RawSubmission) -> Result<NewMethod, AppError> {
    let name = required(raw, "method", "the method's name, e.g. `MyDiffusionPolicy`")?;
    if name.chars().count() > 64
        || !name
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || " -_.+()".contains(c))
    {
        return Err(AppError::invalid(
            "method",
            "`method` must be 1-64 characters of letters, digits, space and - _ . + ( )",
        ));
    }
    let history = match opt(raw, "history") {
        None => None,
        Some(h) => Some(
            h.parse::<i64>()
                .ok()
                .filter(|h| (1..=PolicyManifest::MAX_HISTORY as i64).contains(h))
                .ok_or_else(|| {
                    AppError::invalid(
                        "history",
                        format!(
                            "`history` must be a whole number from 1 to {}",
                            PolicyManifest::MAX_HISTORY
                        ),
                    )
                })?,
        ),
    };
    let short = |k: &str| -> Result<Option<String>, AppError> {
        match opt(raw, k) {
            Some(v) if v.chars().count() > 200 => Err(AppError::invalid(
                k,
                format!("`{k}` must be at most 200 characters"),
            )),
            v => Ok(v),
        }
    };
    let link = |k: &str| -> Result<Option<String>, AppError> {
        match opt(raw, k) {
            Some(v) => Ok(Some(check_url(k, &v, &["http", "https"])?.to_string())),
            None => Ok(None),
        }
    };
    let description = match opt(raw, "description") {
        Some(d) if d.chars().count() > 2000 => {
            return Err(AppError::invalid(
                "description",
                "`description` must be at most 2000 characters",
            ))
        }
        d => d,
    };
    Ok(NewMethod {
        name,
        history,
        backbone: short("backbone")?,
        prediction: short("prediction")?,
        diversity: short("diversity")?,
        code_url: link("code_url")?,
        paper_url: link("paper_url")?,
        description,
    })
}

/// The task and observation type (which must exist for the task).
fn task_fields(raw: &RawSubmission) -> Result<(TaskId, ObsType), AppError> {
    let task_s = required(
        raw,
        "task",
        "one of avoiding, aligning, pushing, sorting-2, sorting-4, sorting-6, stacking, inserting",
    )?;
    let task = TaskId::from_str(&task_s).map_err(|e| AppError::invalid("task", e.to_string()))?;
    let obs_type = match opt(raw, "obs_type") {
        None => ObsType::State,
        Some(o) => ObsType::from_str(&o).map_err(|e| AppError::invalid("obs_type", e))?,
    };
    if obs_type == ObsType::Image && !task.has_image_variant() {
        return Err(AppError::invalid(
            "obs_type",
            format!(
                "task `{task}` has no image-based variant; image observations exist for aligning, sorting-4, sorting-6 and stacking"
            ),
        ));
    }
    Ok((task, obs_type))
}

fn seed_field(raw: &RawSubmission) -> Result<i64, AppError> {
    let seed_s = required(
        raw,
        "training_seed",
        "the seed your policy was trained with (a whole number)",
    )?;
    seed_s
        .parse::<i64>()
        .ok()
        .filter(|s| (0..=i32::MAX as i64).contains(s))
        .ok_or_else(|| {
            AppError::invalid(
                "training_seed",
                format!(
                    "`training_seed` must be a whole number from 0 to 2147483647, got `{seed_s}`"
                ),
            )
        })
}

/// `data_fraction`, rounded so that 0.1 typed twice is the same row.
fn fraction_field(raw: &RawSubmission) -> Result<f64, AppError> {
    Ok(match opt(raw, "data_fraction") {
        None => 1.0,
        Some(f) => f
            .parse::<f64>()
            .ok()
            .filter(|f| f.is_finite() && *f > 0.0 && *f <= 1.0)
            // Rounded so that 0.1 typed twice is the same leaderboard row.
            .map(|f| (f * 10_000.0).round() / 10_000.0)
            .filter(|f| *f > 0.0)
            .ok_or_else(|| {
                AppError::invalid(
                    "data_fraction",
                    format!("`data_fraction` must be a number in (0, 1] (e.g. 0.25), got `{f}`"),
                )
            })?,
    })
}

/// The policy manifest (for a remote endpoint without one: history from the
/// method's `history`, one action per query), checked against the task.
fn manifest_field(
    raw: &RawSubmission,
    task: TaskId,
    obs_type: ObsType,
    history: Option<i64>,
) -> Result<PolicyManifest, AppError> {
    let manifest = match opt(raw, "manifest") {
        Some(m) => {
            let man: PolicyManifest = serde_json::from_str(&m).map_err(|e| {
                AppError::invalid(
                    "manifest",
                    format!("`manifest` is not a valid policy manifest (docs/submission.md): {e}"),
                )
            })?;
            if man.task != task {
                return Err(AppError::invalid(
                    "manifest",
                    format!(
                        "the manifest is for task `{}` but `task` is `{task}`",
                        man.task
                    ),
                ));
            }
            if man.obs_type != obs_type {
                return Err(AppError::invalid(
                    "manifest",
                    format!(
                        "the manifest says obs_type `{}` but `obs_type` is `{obs_type}`",
                        man.obs_type
                    ),
                ));
            }
            man
        }
        None => PolicyManifest {
            task,
            obs_type,
            history: history.unwrap_or(1).max(1) as usize,
            horizon: 1,
            execute: 1,
            normalisation: None,
            window: Default::default(),
        },
    };
    check_manifest_limits(&manifest)?;
    Ok(manifest)
}

/// The manifest limits, as the protocol states them once for intake, the
/// ONNX loader and remote endpoints ([`PolicyManifest::validate`]).
fn check_manifest_limits(manifest: &PolicyManifest) -> Result<(), AppError> {
    manifest
        .validate()
        .map_err(|e| AppError::invalid("manifest", e.to_string()))
}

/// Either an ONNX upload (with its manifest) or a remote endpoint.
fn policy_fields(raw: &mut RawSubmission, limits: &Limits) -> Result<ValidPolicy, AppError> {
    let endpoint = opt(raw, "endpoint_url");
    let has_manifest = opt(raw, "manifest").is_some();
    Ok(match (raw.onnx.take(), endpoint) {
        (Some(_), Some(_)) => {
            return Err(AppError::invalid(
                "endpoint_url",
                "give either an `onnx` file or an `endpoint_url`, not both",
            ))
        }
        (None, None) => {
            return Err(AppError::invalid(
                "onnx",
                "a policy is required: upload an `onnx` file (with `manifest`) or give an `endpoint_url`",
            ))
        }
        (Some(file), None) => {
            if opt(raw, "endpoint_secret").is_some() {
                return Err(AppError::invalid(
                    "endpoint_secret",
                    "`endpoint_secret` goes with an `endpoint_url`; an ONNX upload has none",
                ));
            }
            if !has_manifest {
                return Err(AppError::invalid(
                    "manifest",
                    "an ONNX upload needs its `manifest` (JSON, docs/submission.md)",
                ));
            }
            // Only a size floor here: the worker's loader reads the model itself.
            if file.bytes < 16 {
                return Err(AppError::invalid(
                    "onnx",
                    "the `onnx` file is too small to be an ONNX model",
                ));
            }
            ValidPolicy::Onnx(file)
        }
        (None, Some(u)) => {
            let url = check_url("endpoint_url", &u, &["ws", "wss"])?;
            check_endpoint_host(&url, limits)?;
            ValidPolicy::Remote(url.to_string(), endpoint_secret_field(raw)?)
        }
    })
}

/// The optional `endpoint_secret` of a remote submission (docs/remote-protocol.md,
/// "Shared secret"), taken out of the form so that nothing later holds it
/// but the validated, `Debug`-hiding [`EndpointSecret`]. Not trimmed: the
/// evaluator must send exactly what the endpoint's server was given.
fn endpoint_secret_field(raw: &mut RawSubmission) -> Result<Option<EndpointSecret>, AppError> {
    match raw.text.remove("endpoint_secret") {
        None => Ok(None),
        Some(text) => EndpointSecret::new(&text)
            .map(Some)
            .map_err(|e| AppError::invalid("endpoint_secret", e)),
    }
}

/// Refuses an endpoint whose host is a loopback name or an address literal
/// in a non-public range, with the classifier the worker and the remote
/// client use too (`d3il_protocol::address`); host names are resolved and
/// checked by the worker. The classifier's message names the server setting
/// that would admit the address (`--allow-private-endpoints`), if one would.
fn check_endpoint_host(url: &url::Url, limits: &Limits) -> Result<(), AppError> {
    let host = url.host_str().unwrap_or_default();
    d3il_protocol::address::check_host_literal(host, limits.allow_private_endpoints).map_err(|e| {
        AppError::invalid(
            "endpoint_url",
            format!("`endpoint_url` points to a loopback or private address: {e}"),
        )
    })
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
        race: None,
        job_id: "dry-run".into(),
        suite: v.suite.clone(),
        task: v.task,
        protocol: ProtocolKind::Quick,
        policy,
        manifest: v.manifest.clone(),
        seed: 0,
        limits,
        assets_dir: state.cfg.assets_dir.to_string_lossy().into_owned(),
        dry_run_steps: (!remote).then(|| (2 * v.manifest.execute).max(DRY_RUN_MIN_STEPS)),
        shard: None,
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
    let inserted = match &v.suite {
        Some(suite) => {
            store
                .create_suite_submission(&new, state.cfg.max_attempts, suite, shards)
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
