//! One parser per submission field: each returns the field's value or an
//! error that names the field and says what to send instead. `validate` and
//! `precheck` (the parent module) call them.

use super::{RawSubmission, ValidPolicy};
use crate::error::AppError;
use crate::store::NewMethod;
use d3il_protocol::{EndpointSecret, Limits, ObsType, PolicyManifest, ProtocolKind, TaskId};
use std::str::FromStr;

pub(super) fn opt(raw: &RawSubmission, k: &str) -> Option<String> {
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

pub(super) fn protocol_field(raw: &RawSubmission) -> Result<ProtocolKind, AppError> {
    match opt(raw, "protocol") {
        None => Ok(ProtocolKind::Paper),
        Some(p) => ProtocolKind::from_str(&p).map_err(|e| AppError::invalid("protocol", e)),
    }
}

/// The method's name and properties.
pub(super) fn method_fields(raw: &RawSubmission) -> Result<NewMethod, AppError> {
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
pub(super) fn task_fields(raw: &RawSubmission) -> Result<(TaskId, ObsType), AppError> {
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

pub(super) fn seed_field(raw: &RawSubmission) -> Result<i64, AppError> {
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
pub(super) fn fraction_field(raw: &RawSubmission) -> Result<f64, AppError> {
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
pub(super) fn manifest_field(
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
pub(super) fn policy_fields(
    raw: &mut RawSubmission,
    limits: &Limits,
) -> Result<ValidPolicy, AppError> {
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
