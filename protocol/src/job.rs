//! A job is what the server hands to a sandboxed `d3il worker` (as one JSON
//! document on stdin); the worker answers with JSON lines of [`WorkerMessage`].

use crate::results::EvalResult;
use crate::task::{ObsType, ProtocolKind, TaskId};
use serde::{Deserialize, Serialize};

mod kind;
pub use kind::*;

/// Normalisation statistics a policy expects if they are not baked into the graph.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, Default)]
pub struct Normalisation {
    pub obs_mean: Option<Vec<f32>>,
    pub obs_std: Option<Vec<f32>>,
    pub act_mean: Option<Vec<f32>>,
    pub act_std: Option<Vec<f32>>,
}

/// How a policy's observation window starts an episode (docs/submission.md
/// "Window at episode start").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum WindowMode {
    /// Always k observations; at episode start the window is padded by
    /// repeating the first observation.
    #[default]
    Pad,
    /// The window grows from 1 to k observations at episode start, as the
    /// reference agents' deques do (BeT, GPT-BC, BESO). Needs a model whose
    /// window dimension is symbolic.
    Grow,
}

impl WindowMode {
    pub fn as_str(self) -> &'static str {
        match self {
            WindowMode::Pad => "pad",
            WindowMode::Grow => "grow",
        }
    }
}

impl std::fmt::Display for WindowMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

/// A manifest field that breaks a limit; `field` names it, the message says
/// what to fix.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("manifest `{field}`: {message}")]
pub struct ManifestError {
    pub field: &'static str,
    pub message: String,
}

/// The small JSON manifest that travels with an ONNX file (docs/submission.md).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PolicyManifest {
    pub task: TaskId,
    #[serde(default = "default_obs_type")]
    pub obs_type: ObsType,
    /// History length k (observations per query).
    #[serde(default = "one")]
    pub history: usize,
    /// Action chunk length H returned per query.
    #[serde(default = "one")]
    pub horizon: usize,
    /// Actions executed per query, E <= H.
    #[serde(default = "one")]
    pub execute: usize,
    #[serde(default)]
    pub normalisation: Option<Normalisation>,
    /// Episode-start semantics of the observation window (default `pad`).
    #[serde(default)]
    pub window: WindowMode,
}

impl PolicyManifest {
    /// Largest history k a manifest may declare (the reference uses at most 5).
    pub const MAX_HISTORY: usize = 64;
    /// Largest chunk length H (and so execute E) a manifest may declare.
    pub const MAX_HORIZON: usize = 1024;

    /// The manifest limits, stated once for every consumer (intake, ONNX
    /// loading, remote endpoints): 1 ≤ history ≤ [`Self::MAX_HISTORY`],
    /// 1 ≤ execute ≤ horizon ≤ [`Self::MAX_HORIZON`], and normalisation
    /// vectors finite with positive standard deviations.
    pub fn validate(&self) -> Result<(), ManifestError> {
        let err = |field, message: String| Err(ManifestError { field, message });
        if !(1..=Self::MAX_HISTORY).contains(&self.history) {
            return err(
                "history",
                format!(
                    "history k = {} must be from 1 to {}",
                    self.history,
                    Self::MAX_HISTORY
                ),
            );
        }
        if !(1..=Self::MAX_HORIZON).contains(&self.horizon) {
            return err(
                "horizon",
                format!(
                    "horizon H = {} must be from 1 to {}",
                    self.horizon,
                    Self::MAX_HORIZON
                ),
            );
        }
        if !(1..=self.horizon).contains(&self.execute) {
            return err(
                "execute",
                format!(
                    "execute E = {} must be from 1 to the horizon H = {}",
                    self.execute, self.horizon
                ),
            );
        }
        if let Some(n) = &self.normalisation {
            for (field, v) in [
                ("normalisation.obs_mean", &n.obs_mean),
                ("normalisation.obs_std", &n.obs_std),
                ("normalisation.act_mean", &n.act_mean),
                ("normalisation.act_std", &n.act_std),
            ] {
                let Some(v) = v else { continue };
                if v.iter().any(|x| !x.is_finite()) {
                    return err(field, "contains a non-finite value".into());
                }
                if field.ends_with("std") && v.iter().any(|x| *x <= 0.0) {
                    return err(field, "must be positive everywhere".into());
                }
            }
        }
        Ok(())
    }

    /// [`Self::validate`] plus the checks against the task the policy is run
    /// on: the task matches and normalisation vectors have the task's lengths.
    pub fn validate_for(&self, spec: &crate::TaskSpec) -> Result<(), ManifestError> {
        self.validate()?;
        if self.task != spec.task {
            return Err(ManifestError {
                field: "task",
                message: format!(
                    "it is for task {} but is being evaluated on {}",
                    self.task, spec.task
                ),
            });
        }
        if let Some(n) = &self.normalisation {
            for (field, v, len) in [
                ("normalisation.obs_mean", &n.obs_mean, spec.obs_dim),
                ("normalisation.obs_std", &n.obs_std, spec.obs_dim),
                ("normalisation.act_mean", &n.act_mean, spec.act_dim),
                ("normalisation.act_std", &n.act_std, spec.act_dim),
            ] {
                if let Some(v) = v {
                    if v.len() != len {
                        return Err(ManifestError {
                            field,
                            message: format!(
                                "has {} entries but task {} needs {len}",
                                v.len(),
                                spec.task
                            ),
                        });
                    }
                }
            }
        }
        Ok(())
    }
}

fn one() -> usize {
    1
}
fn default_obs_type() -> ObsType {
    ObsType::State
}

/// The shared secret a remote endpoint expects from the evaluator
/// (docs/remote-protocol.md, "Shared secret"). Its `Debug` and `Display` print
/// no character of it, so a logged job or error cannot leak it; only
/// [`EndpointSecret::expose`] gives the text, for the handshake header.
#[derive(Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct EndpointSecret(String);

impl EndpointSecret {
    /// Shortest secret accepted: a guessable one would protect nothing.
    pub const MIN_LEN: usize = 16;
    /// Longest secret accepted (it travels in an HTTP header).
    pub const MAX_LEN: usize = 256;

    /// A secret of `MIN_LEN..=MAX_LEN` visible ASCII characters (no spaces
    /// or control characters: it is sent as an HTTP header value).
    pub fn new(text: &str) -> Result<Self, String> {
        let n = text.chars().count();
        if !(Self::MIN_LEN..=Self::MAX_LEN).contains(&n) {
            return Err(format!(
                "the endpoint secret has {n} characters; give {} to {} (e.g. `python3 -c 'import secrets; print(secrets.token_urlsafe(32))'`)",
                Self::MIN_LEN,
                Self::MAX_LEN
            ));
        }
        if let Some(c) = text.chars().find(|c| !c.is_ascii_graphic()) {
            return Err(format!(
                "the endpoint secret contains {c:?}; use visible ASCII characters only (no spaces), e.g. `secrets.token_urlsafe(32)`"
            ));
        }
        Ok(EndpointSecret(text.to_string()))
    }

    /// Environment variable holding an endpoint's secret: `d3il eval` sends
    /// it to a `ws(s)://` policy, `d3il submit --endpoint` (and the Python
    /// client's command line) submits it, the Python policy server expects it.
    pub const ENV: &'static str = "D3IL_ENDPOINT_SECRET";

    /// The secret in `$D3IL_ENDPOINT_SECRET`, if it is set and not empty.
    pub fn from_env() -> Result<Option<Self>, String> {
        match std::env::var(Self::ENV) {
            Ok(text) if !text.is_empty() => Self::new(&text)
                .map(Some)
                .map_err(|e| format!("${}: {e}", Self::ENV)),
            _ => Ok(None),
        }
    }

    /// The secret's text, for the one place that sends it.
    pub fn expose(&self) -> &str {
        &self.0
    }
}

impl std::fmt::Debug for EndpointSecret {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("EndpointSecret(<hidden>)")
    }
}

/// Where the policy comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum PolicySource {
    /// An ONNX file on disk that the worker may read (the only file it may read
    /// besides the assets).
    Onnx { path: String, sha256: String },
    /// A remote endpoint speaking docs/remote-protocol.md; with `secret`, the
    /// evaluator sends it in the WebSocket handshake (`Authorization: Bearer`)
    /// so that a published endpoint can serve only the evaluator.
    Remote {
        url: String,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        secret: Option<EndpointSecret>,
    },
    /// A built-in scripted reference policy (sanity baselines), e.g. `avoiding:path=3`.
    Scripted { name: String },
}

/// Resource limits for one worker. Every field has a default and a config knob.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// Address-space limit in bytes.
    pub memory_bytes: u64,
    /// CPU seconds.
    pub cpu_seconds: u64,
    /// Wall-clock seconds (enforced by the parent).
    pub wall_seconds: u64,
    /// Maximum open file descriptors.
    pub open_files: u64,
    /// Maximum size of any file the worker writes.
    pub file_size_bytes: u64,
    /// Per-request deadline for remote policies, milliseconds.
    pub remote_deadline_ms: u64,
    /// Maximum size of one remote frame, bytes.
    pub remote_frame_bytes: u64,
    /// Allow remote endpoints on loopback/private addresses: always for
    /// `d3il eval` (the user's own machine), for a server only when its
    /// operator passes `--allow-private-endpoints` (trusted set-ups, tests).
    pub allow_private_endpoints: bool,
    /// Extra CA certificate(s), PEM text, trusted for `wss://` endpoints besides
    /// the public web roots (tests, private deployments). The parent fills it
    /// from `$D3IL_EXTRA_CA_FILE`; the worker itself reads no CA file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extra_ca_pem: Option<String>,
}

impl Limits {
    /// Environment variable naming a PEM file of extra CA certificates for
    /// `wss://` endpoints. Read by the parent (and by an unsandboxed
    /// `d3il eval`), which passes the PEM in [`Limits::extra_ca_pem`].
    pub const EXTRA_CA_ENV: &'static str = "D3IL_EXTRA_CA_FILE";

    /// The PEM text of the file `$D3IL_EXTRA_CA_FILE` names, if it is set.
    pub fn extra_ca_from_env() -> Result<Option<String>, String> {
        let Some(path) = std::env::var_os(Self::EXTRA_CA_ENV).filter(|p| !p.is_empty()) else {
            return Ok(None);
        };
        std::fs::read_to_string(&path).map(Some).map_err(|e| {
            format!(
                "cannot read the extra CA file {} named by ${} ({e}); give a readable PEM file of CA certificates or unset it",
                std::path::Path::new(&path).display(),
                Self::EXTRA_CA_ENV
            )
        })
    }
}

impl Default for Limits {
    fn default() -> Self {
        Limits {
            memory_bytes: 4 << 30,
            cpu_seconds: 3600,
            wall_seconds: 3600,
            open_files: 256,
            file_size_bytes: 64 << 20,
            remote_deadline_ms: 10_000,
            remote_frame_bytes: 64 << 20,
            allow_private_endpoints: false,
            extra_ca_pem: None,
        }
    }
}

/// One evaluation job.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Job {
    /// Opaque id chosen by the caller (the server's job id).
    pub job_id: String,
    pub task: TaskId,
    #[serde(default)]
    pub protocol: ProtocolKind,
    pub policy: PolicySource,
    pub manifest: PolicyManifest,
    /// Seed of the evaluator's RNG (policy noise, rollout sampling).
    #[serde(default)]
    pub seed: u64,
    #[serde(default)]
    pub limits: Limits,
    /// Directory holding the project's assets (MJCF, context sets). The worker
    /// may read it and nothing else besides the policy file.
    pub assets_dir: String,
    /// A submission-time dry run: every rollout ends after this many env
    /// steps, so the whole pipeline (loading, observations, windows, images,
    /// batched inference, action checks) runs in seconds; the result is
    /// discarded. `None` for real evaluations.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dry_run_steps: Option<usize>,
    /// What the job evaluates and answers with: the whole protocol, one
    /// shard, the perturbation suite, a shard of it, or a race. On the wire
    /// its fields sit beside the job's own (`"kind": "suite_shard", "suite":
    /// "robustness", "shard": {...}`), see [`JobKind`].
    #[serde(flatten)]
    pub kind: JobKind,
    /// The build identity the result's manifest records (the server and
    /// `d3il eval` know the fingerprint; a sandboxed worker cannot compute it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build: Option<crate::results::BuildIdentity>,
}

/// What a worker's evaluation produced, one variant per [`JobKind`].
#[derive(Debug, Clone, PartialEq)]
pub enum Evaluated {
    Result(Box<EvalResult>),
    Part(Box<crate::shard::EvalPart>),
    /// A [`JobKind::Suite`] job: level 0 and every perturbed level.
    Robustness(Box<crate::robustness::RobustnessResult>),
    /// A [`JobKind::SuiteShard`] job: the shard's part of level 0 and of
    /// every level.
    SuitePart(Box<crate::robustness::RobustnessPart>),
    /// A [`JobKind::Race`] job: the race's report.
    Race(Box<crate::race::RaceReport>),
}

impl From<EvalResult> for Evaluated {
    fn from(r: EvalResult) -> Self {
        Evaluated::Result(Box::new(r))
    }
}

/// Categories of failure a submitter can act on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorKind {
    /// The job document itself was invalid.
    BadJob,
    /// The ONNX file could not be parsed or does not match the task.
    BadModel,
    /// The policy produced NaN/inf or wrongly shaped actions.
    BadAction,
    /// A remote endpoint misbehaved (late, oversized, malformed, disconnected).
    Remote,
    /// The endpoint URL was refused (scheme, host or address range).
    BadEndpoint,
    /// A resource limit was exceeded.
    MemoryLimit,
    CpuLimit,
    WallClock,
    /// The worker died from a signal or exited without a result.
    Crashed,
    /// The worker printed something that is not the protocol.
    ProtocolViolation,
    /// A bug or environment problem on our side.
    Internal,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct WorkerError {
    pub kind: ErrorKind,
    /// A message the submitter can act on.
    pub message: String,
}

/// One line the worker prints on stdout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum WorkerMessage {
    /// Which confinement mechanisms are in force (first line).
    Sandbox {
        mechanisms: Vec<SandboxMechanism>,
    },
    /// Rollouts done, and the initial states newly finished in the
    /// evaluation's random order ([`crate::progress::Progress`]).
    Progress(crate::progress::Progress),
    Result(Box<EvalResult>),
    /// The part of one shard (a [`JobKind::Shard`] job).
    Part(Box<crate::shard::EvalPart>),
    /// The robustness document of a [`JobKind::Suite`] job.
    Robustness(Box<crate::robustness::RobustnessResult>),
    /// The part of one shard of a [`JobKind::SuiteShard`] job.
    SuitePart(Box<crate::robustness::RobustnessPart>),
    /// The report of a [`JobKind::Race`] job.
    Race(Box<crate::race::RaceReport>),
    Error(WorkerError),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SandboxMechanism {
    pub name: String,
    pub active: bool,
    pub detail: String,
}

/// Documented worker exit codes.
pub mod exit_code {
    pub const OK: i32 = 0;
    /// The job failed with a structured error (printed as the last line).
    pub const JOB_FAILED: i32 = 2;
    /// The job document could not be read.
    pub const BAD_JOB: i32 = 3;
    /// The sandbox could not be set up and confinement was required.
    pub const SANDBOX_FAILED: i32 = 4;
}

#[cfg(test)]
mod tests;
