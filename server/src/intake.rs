//! Reading, validating and accepting a submission (shared by the JSON API and
//! the HTML submit form). Every error names the offending field.

use crate::error::AppError;
use crate::queue::JobRunner;
use crate::state::AppState;
use crate::store::{NewMethod, NewPolicy, NewSubmission, SeedKey, Submitter};
use axum::extract::multipart::{Field, Multipart, MultipartError};
use axum::http::{header, HeaderMap, StatusCode};
use d3il_protocol::{
    ErrorKind, Job, Limits, ObsType, PolicyManifest, PolicySource, ProtocolKind, TaskId,
};
use std::collections::HashMap;
use std::str::FromStr;
use std::sync::Arc;

/// Text fields are small; anything longer is refused.
const MAX_TEXT_FIELD: usize = 64 << 10;

/// Fields accepted in a submission (multipart/form-data).
pub const TEXT_FIELDS: &[&str] = &[
    "method",
    "history",
    "backbone",
    "prediction",
    "diversity",
    "code_url",
    "paper_url",
    "description",
    "task",
    "obs_type",
    "training_seed",
    "data_fraction",
    "protocol",
    "manifest",
    "endpoint_url",
    "token",
];

#[derive(Debug, Default)]
pub struct RawSubmission {
    pub text: HashMap<String, String>,
    pub onnx: Option<Vec<u8>>,
}

/// Refuses a body whose declared length is over the limit before reading any
/// of it (issue 7: oversized uploads refused before they are buffered).
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

fn multipart_err(e: MultipartError, max: usize) -> AppError {
    if e.status() == StatusCode::PAYLOAD_TOO_LARGE {
        too_large(max)
    } else {
        AppError::Invalid {
            field: None,
            message: format!("the request body is not valid multipart/form-data: {e}"),
        }
    }
}

/// Streams the multipart body, keeping at most `max` bytes of upload: the
/// file is read chunk by chunk and refused as soon as it passes the limit.
pub async fn read_multipart(mp: Multipart, max: usize) -> Result<RawSubmission, AppError> {
    Ok(read_multipart_inner(mp, max, None).await?.0)
}

/// Like [`read_multipart`] for the HTML form, whose credentials travel in its
/// `token` field: the token is authenticated before the first byte of a file
/// field is read (the form puts it first), so a request without a valid token
/// is refused before any upload is buffered.
pub async fn read_form_authenticated(
    mp: Multipart,
    max: usize,
    state: &AppState,
) -> Result<(RawSubmission, Submitter), AppError> {
    let (raw, who) = read_multipart_inner(mp, max, Some(state)).await?;
    let who = who.ok_or_else(|| AppError::Unauthorized("the `token` field is required".into()))?;
    Ok((raw, who))
}

async fn authenticate_form_token(
    state: &AppState,
    raw: &RawSubmission,
) -> Result<Submitter, AppError> {
    let token = raw
        .text
        .get("token")
        .map(|t| t.trim().to_string())
        .filter(|t| !t.is_empty())
        .ok_or_else(|| {
            AppError::Unauthorized(
                "the `token` field is required (before the file fields): paste the API token from `d3il token create --name <you>`"
                    .into(),
            )
        })?;
    crate::auth::authenticate_token(state, &token).await
}

async fn read_multipart_inner(
    mut mp: Multipart,
    max: usize,
    auth: Option<&AppState>,
) -> Result<(RawSubmission, Option<Submitter>), AppError> {
    let mut raw = RawSubmission::default();
    let mut who = None;
    while let Some(mut field) = mp.next_field().await.map_err(|e| multipart_err(e, max))? {
        let name = field.name().unwrap_or_default().to_string();
        if let (Some(state), None, true) = (auth, &who, name == "onnx" || name == "manifest_file") {
            who = Some(authenticate_form_token(state, &raw).await?);
        }
        if name == "onnx" {
            let bytes = read_limited(&mut field, max, &name).await?;
            // Browsers send an empty file part when no file was chosen.
            if !bytes.is_empty() {
                raw.onnx = Some(bytes);
            }
        } else if name == "manifest_file" {
            let bytes = read_limited(&mut field, MAX_TEXT_FIELD, "manifest").await?;
            if !bytes.is_empty() {
                let text = String::from_utf8(bytes).map_err(|_| {
                    AppError::invalid("manifest", "the manifest must be UTF-8 JSON")
                })?;
                raw.text.insert("manifest".into(), text);
            }
        } else if TEXT_FIELDS.contains(&name.as_str()) {
            let bytes = read_limited(&mut field, MAX_TEXT_FIELD, &name).await?;
            let text = String::from_utf8(bytes)
                .map_err(|_| AppError::invalid(&name, format!("`{name}` must be UTF-8 text")))?;
            raw.text.insert(name, text);
        } else {
            return Err(AppError::invalid(
                &name,
                format!(
                    "unknown field `{name}`; accepted fields: onnx, manifest_file, {}",
                    TEXT_FIELDS.join(", ")
                ),
            ));
        }
    }
    if let (Some(state), None) = (auth, &who) {
        who = Some(authenticate_form_token(state, &raw).await?);
    }
    Ok((raw, who))
}

async fn read_limited(field: &mut Field<'_>, max: usize, name: &str) -> Result<Vec<u8>, AppError> {
    let mut buf = Vec::new();
    while let Some(chunk) = field.chunk().await.map_err(|e| multipart_err(e, max))? {
        if buf.len() + chunk.len() > max {
            return Err(if name == "onnx" {
                too_large(max)
            } else {
                AppError::invalid(name, format!("`{name}` is longer than {max} bytes"))
            });
        }
        buf.extend_from_slice(&chunk);
    }
    Ok(buf)
}

/// A submission that passed validation.
#[derive(Debug, Clone)]
pub struct ValidSubmission {
    pub method: NewMethod,
    pub task: TaskId,
    pub obs_type: ObsType,
    pub training_seed: i64,
    pub data_fraction: f64,
    pub protocol: ProtocolKind,
    pub manifest: PolicyManifest,
    pub policy: ValidPolicy,
}

#[derive(Debug, Clone)]
pub enum ValidPolicy {
    Onnx(Vec<u8>),
    Remote(String),
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
pub fn validate(raw: &RawSubmission, limits: &Limits) -> Result<ValidSubmission, AppError> {
    let method = method_fields(raw)?;
    let (task, obs_type) = task_fields(raw)?;
    let training_seed = seed_field(raw)?;
    let data_fraction = fraction_field(raw)?;
    let protocol = match opt(raw, "protocol") {
        None => ProtocolKind::Paper,
        Some(p) => ProtocolKind::from_str(&p).map_err(|e| AppError::invalid("protocol", e))?,
    };
    let manifest = manifest_field(raw, task, obs_type, method.history)?;
    let policy = policy_fields(raw, limits)?;
    Ok(ValidSubmission {
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
                .filter(|h| (1..=1000).contains(h))
                .ok_or_else(|| {
                    AppError::invalid("history", "`history` must be a whole number from 1 to 1000")
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

/// The limits on a manifest's history, horizon and execute.
fn check_manifest_limits(manifest: &PolicyManifest) -> Result<(), AppError> {
    for (k, v) in [
        ("history", manifest.history),
        ("horizon", manifest.horizon),
        ("execute", manifest.execute),
    ] {
        if !(1..=1000).contains(&v) {
            return Err(AppError::invalid(
                "manifest",
                format!("manifest `{k}` must be from 1 to 1000, got {v}"),
            ));
        }
    }
    if manifest.execute > manifest.horizon {
        return Err(AppError::invalid(
            "manifest",
            format!(
                "manifest `execute` ({}) cannot exceed `horizon` ({})",
                manifest.execute, manifest.horizon
            ),
        ));
    }
    Ok(())
}

/// Either an ONNX upload (with its manifest) or a remote endpoint.
fn policy_fields(raw: &RawSubmission, limits: &Limits) -> Result<ValidPolicy, AppError> {
    let endpoint = opt(raw, "endpoint_url");
    Ok(match (&raw.onnx, endpoint) {
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
        (Some(bytes), None) => {
            if opt(raw, "manifest").is_none() {
                return Err(AppError::invalid(
                    "manifest",
                    "an ONNX upload needs its `manifest` (JSON, docs/submission.md)",
                ));
            }
            // Only a size floor here: the worker's loader reads the model itself.
            if bytes.len() < 16 {
                return Err(AppError::invalid(
                    "onnx",
                    "the `onnx` file is too small to be an ONNX model",
                ));
            }
            ValidPolicy::Onnx(bytes.clone())
        }
        (None, Some(u)) => {
            let url = check_url("endpoint_url", &u, &["ws", "wss"])?;
            check_endpoint_host(&url, limits)?;
            ValidPolicy::Remote(url.to_string())
        }
    })
}

/// Refuses an endpoint whose host is a loopback name or an address literal
/// in a non-public range, with the classifier the worker and the remote
/// client use too (`d3il_protocol::address`); host names are resolved and
/// checked by the worker.
fn check_endpoint_host(url: &url::Url, limits: &Limits) -> Result<(), AppError> {
    let host = url.host_str().unwrap_or_default();
    d3il_protocol::address::check_host_literal(host, limits.allow_private_endpoints).map_err(|e| {
        AppError::invalid(
            "endpoint_url",
            format!(
                "`endpoint_url` points to a loopback or private address ({e}); use a public host"
            ),
        )
    })
}

/// Runs a remote endpoint through a short quick-protocol evaluation before it
/// is queued; any failure is reported to the submitter and nothing is stored.
pub async fn endpoint_dry_run(
    runner: Arc<dyn JobRunner>,
    state: &AppState,
    v: &ValidSubmission,
    url: &str,
) -> Result<(), AppError> {
    let mut limits = state.cfg.limits.clone();
    limits.wall_seconds = limits.wall_seconds.min(120);
    let job = Job {
        job_id: "dry-run".into(),
        task: v.task,
        protocol: ProtocolKind::Quick,
        policy: PolicySource::Remote { url: url.into() },
        manifest: v.manifest.clone(),
        seed: 0,
        limits,
        assets_dir: state.cfg.assets_dir.to_string_lossy().into_owned(),
    };
    let report = tokio::task::spawn_blocking(move || runner.run(&job, &mut |_, _| {}))
        .await
        .map_err(|e| AppError::Internal(format!("dry-run panicked: {e}")))?;
    match report.outcome {
        Ok(_) => Ok(()),
        Err(e) if e.kind == ErrorKind::Internal => Err(AppError::Internal(e.message)),
        Err(e) => Err(AppError::EndpointRejected {
            kind: serde_json::to_value(e.kind)
                .ok()
                .and_then(|v| v.as_str().map(str::to_string))
                .unwrap_or_default(),
            message: format!(
                "the endpoint failed the conformance dry-run (docs/remote-protocol.md): {}",
                e.message
            ),
        }),
    }
}

/// Stores a validated submission and queues its job; returns the submission id
/// once it is durable.
pub async fn accept(
    state: &AppState,
    v: ValidSubmission,
    who: &Submitter,
) -> Result<i64, AppError> {
    let store = &state.store;
    if let Some(existing) = store.method_by_name(&v.method.name).await? {
        if existing.submitter_id.is_some() && existing.submitter_id != Some(who.id) {
            return Err(AppError::Conflict {
                field: Some("method".into()),
                message: format!(
                    "method `{}` belongs to another submitter; choose a different name",
                    v.method.name
                ),
            });
        }
        // A duplicate seed is refused before an endpoint's dry-run (which can
        // take minutes) or an ONNX write; create_submission checks again
        // under the write lock. A new method cannot hold the seed yet.
        store
            .check_seed_free(&SeedKey {
                method_id: existing.id,
                task: v.task,
                obs_type: v.obs_type,
                data_fraction: v.data_fraction,
                protocol: v.protocol,
                training_seed: v.training_seed,
            })
            .await?;
    }
    if let ValidPolicy::Remote(url) = &v.policy {
        endpoint_dry_run(state.runner.clone(), state, &v, url).await?;
    }
    // Only an accepted submission creates its method (a refused dry-run
    // leaves nothing behind).
    let method = store.ensure_method(&v.method, Some(who.id)).await?;
    let policy = match &v.policy {
        ValidPolicy::Onnx(bytes) => {
            let (sha256, path) = store.store_onnx(bytes).await?;
            NewPolicy::Onnx {
                sha256,
                bytes: bytes.len() as i64,
                path,
            }
        }
        ValidPolicy::Remote(url) => NewPolicy::Remote { url: url.clone() },
    };
    let manifest_json = serde_json::to_string(&v.manifest)
        .map_err(|e| AppError::Internal(format!("manifest encoding: {e}")))?;
    let id = store
        .create_submission(
            &NewSubmission {
                method_id: method.id,
                submitter_id: Some(who.id),
                task: v.task,
                obs_type: v.obs_type,
                training_seed: v.training_seed,
                data_fraction: v.data_fraction,
                protocol: v.protocol,
                policy,
                manifest_json,
            },
            state.cfg.max_attempts,
        )
        .await?;
    state.signal.job_queued();
    tracing::info!("submission {id} accepted from `{}`", who.name);
    Ok(id)
}
