//! Reading a submission's multipart body. Text fields are small and kept in
//! memory; the ONNX file is streamed to a temporary file in the policy store
//! with a running SHA-256 and never held whole. Before the first byte of the
//! file is read the caller is known (bearer token, or the form's `token`
//! field) and the fields sent before it are checked (method ownership, task,
//! manifest, seed, disk quota), so a refused request stores nothing (the
//! rest of its body is read on and discarded, [`crate::linger`], so that the
//! client reads the refusal).

use super::{precheck, too_large};
use crate::error::AppError;
use crate::state::AppState;
use crate::store::Submitter;
use axum::extract::multipart::{Field, Multipart, MultipartError};
use axum::http::StatusCode;
use sha2::{Digest, Sha256};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

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
    "endpoint_secret",
    "suite",
    "token",
];

#[derive(Debug, Default)]
pub struct RawSubmission {
    pub text: HashMap<String, String>,
    pub onnx: Option<UploadedFile>,
}

/// An upload on disk under a temporary name, with its SHA-256 and size. The
/// file is deleted when this is dropped unless the store took it
/// ([`UploadedFile::take_path`]): a refused or failed request leaves nothing.
#[derive(Debug)]
pub struct UploadedFile {
    tmp: Option<PathBuf>,
    pub sha256: String,
    pub bytes: u64,
}

impl UploadedFile {
    /// The temporary file (None once taken).
    pub fn path(&self) -> Option<&Path> {
        self.tmp.as_deref()
    }

    /// Hands the temporary file over; it is no longer deleted on drop.
    pub fn take_path(&mut self) -> Option<PathBuf> {
        self.tmp.take()
    }
}

impl Drop for UploadedFile {
    fn drop(&mut self) {
        if let Some(p) = self.tmp.take() {
            if let Err(e) = std::fs::remove_file(&p) {
                tracing::warn!("cannot remove refused upload {}: {e}", p.display());
            }
        }
    }
}

/// Who sends the body: known from the bearer token, or to be read from the
/// form's `token` field (which the HTML form puts first).
pub enum Caller {
    Known(Submitter),
    FormToken,
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

/// Reads the body into `raw`: text fields into memory, the `onnx` file
/// streamed to a temporary file after the caller and the fields before it
/// were checked. On an error `raw` holds the fields read so far (the HTML
/// form shows them again).
pub async fn read_multipart(
    mut mp: Multipart,
    state: &AppState,
    caller: Caller,
    raw: &mut RawSubmission,
) -> Result<Submitter, AppError> {
    let max = state.cfg.max_upload_bytes;
    let mut who = match caller {
        Caller::Known(w) => Some(w),
        Caller::FormToken => None,
    };
    while let Some(mut field) = mp.next_field().await.map_err(|e| multipart_err(e, max))? {
        let name = field.name().unwrap_or_default().to_string();
        if who.is_none() && (name == "onnx" || name == "manifest_file") {
            who = Some(authenticate_form_token(state, raw).await?);
        }
        if name == "onnx" {
            let Some(w) = &who else {
                return Err(AppError::Internal("caller unknown before the file".into()));
            };
            if raw.onnx.is_some() {
                return Err(AppError::invalid("onnx", "send one `onnx` file only"));
            }
            let quota = precheck(state, raw, w).await?;
            let file = stream_to_file(state, &mut field, quota).await?;
            // Browsers send an empty file part when no file was chosen.
            if file.bytes > 0 {
                raw.onnx = Some(file);
            }
        } else if name == "manifest_file" {
            let bytes = read_limited(&mut field, MAX_TEXT_FIELD, "manifest", max).await?;
            if !bytes.is_empty() {
                let text = String::from_utf8(bytes).map_err(|_| {
                    AppError::invalid("manifest", "the manifest must be UTF-8 JSON")
                })?;
                raw.text.insert("manifest".into(), text);
            }
        } else if TEXT_FIELDS.contains(&name.as_str()) {
            let bytes = read_limited(&mut field, MAX_TEXT_FIELD, &name, max).await?;
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
    match who {
        Some(w) => Ok(w),
        None => authenticate_form_token(state, raw).await,
    }
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

async fn read_limited(
    field: &mut Field<'_>,
    limit: usize,
    name: &str,
    max_body: usize,
) -> Result<Vec<u8>, AppError> {
    let mut buf = Vec::new();
    while let Some(chunk) = field
        .chunk()
        .await
        .map_err(|e| multipart_err(e, max_body))?
    {
        if buf.len() + chunk.len() > limit {
            return Err(AppError::invalid(
                name,
                format!("`{name}` is longer than {limit} bytes"),
            ));
        }
        buf.extend_from_slice(&chunk);
    }
    Ok(buf)
}

/// How many more bytes this upload may have: the upload limit and what is
/// left of the submitter's disk quota.
#[derive(Debug, Clone, Copy)]
pub struct Quota {
    pub max_upload: usize,
    /// Bytes the submitter's files use now, and the cap (None: no cap).
    pub disk_used: u64,
    pub disk_cap: Option<u64>,
}

impl Quota {
    fn check(&self, bytes: u64) -> Result<(), AppError> {
        if bytes > self.max_upload as u64 {
            return Err(too_large(self.max_upload));
        }
        if let Some(cap) = self.disk_cap {
            if self.disk_used + bytes > cap {
                return Err(disk_quota_error(self.disk_used, cap));
            }
        }
        Ok(())
    }
}

/// The error of a submitter over `--max-disk-mb-per-submitter`.
pub fn disk_quota_error(used: u64, cap: u64) -> AppError {
    AppError::PayloadTooLarge(format!(
        "this upload would take your stored policy files over the disk limit of {} MiB per submitter \
         (--max-disk-mb-per-submitter); your accepted submissions use {:.1} MiB. Files of failed \
         submissions do not count; ask the operator to raise the limit",
        cap >> 20,
        used as f64 / (1u64 << 20) as f64
    ))
}

/// Bytes read before they are handed to the writer thread.
const WRITE_BATCH: usize = 1 << 20;

/// The open temporary file and the running hash.
type Sink = (std::fs::File, Sha256);

async fn join_write(p: tokio::task::JoinHandle<std::io::Result<Sink>>) -> Result<Sink, AppError> {
    p.await
        .map_err(|e| AppError::Internal(format!("upload writer panicked: {e}")))?
        .map_err(|e| AppError::Internal(format!("writing the upload: {e}")))
}

/// Streams the file part to a temporary file in the policy store, hashing as
/// it goes and refusing it as soon as it passes the quota (the partial file is
/// deleted). At most `--max-concurrent-uploads` stream at once; the others
/// wait before reading their body.
async fn stream_to_file(
    state: &AppState,
    field: &mut Field<'_>,
    quota: Quota,
) -> Result<UploadedFile, AppError> {
    let _permit = state
        .uploads
        .acquire()
        .await
        .map_err(|_| AppError::Internal("upload semaphore closed".into()))?;
    let path = state.store.new_upload_path();
    let io = |e: std::io::Error| AppError::Internal(format!("writing the upload: {e}"));
    let file = std::fs::File::create(&path).map_err(io)?;
    // From here on the guard deletes the file on every early return.
    let mut up = UploadedFile {
        tmp: Some(path),
        sha256: String::new(),
        bytes: 0,
    };
    // Hashing and writing run on a blocking thread, a batch at a time, while
    // the next batch is read: the async workers only parse the body.
    let mut sink = Some((file, Sha256::new()));
    let mut pending: Option<tokio::task::JoinHandle<std::io::Result<Sink>>> = None;
    let mut batch: Vec<axum::body::Bytes> = Vec::new();
    let mut batch_len = 0usize;
    loop {
        let chunk = field
            .chunk()
            .await
            .map_err(|e| multipart_err(e, quota.max_upload))?;
        let last = chunk.is_none();
        if let Some(c) = chunk {
            up.bytes += c.len() as u64;
            state.telemetry.upload_bytes.inc_by(c.len() as u64);
            quota.check(up.bytes)?;
            batch_len += c.len();
            batch.push(c);
        }
        if batch_len >= WRITE_BATCH || (last && !batch.is_empty()) {
            if let Some(p) = pending.take() {
                sink = Some(join_write(p).await?);
            }
            let (mut f, mut h) = sink
                .take()
                .ok_or_else(|| AppError::Internal("upload writer lost".into()))?;
            let b = std::mem::take(&mut batch);
            batch_len = 0;
            pending = Some(tokio::task::spawn_blocking(move || {
                use std::io::Write;
                for c in &b {
                    h.update(c);
                    f.write_all(c)?;
                }
                Ok((f, h))
            }));
        }
        if last {
            break;
        }
    }
    if let Some(p) = pending.take() {
        sink = Some(join_write(p).await?);
    }
    let (file, hash) = sink.ok_or_else(|| AppError::Internal("upload writer lost".into()))?;
    tokio::task::spawn_blocking(move || file.sync_all())
        .await
        .map_err(|e| AppError::Internal(format!("upload writer panicked: {e}")))?
        .map_err(io)?;
    up.sha256 = hex::encode(hash.finalize());
    Ok(up)
}
