//! A job is what the server hands to a sandboxed `d3il worker` (as one JSON
//! document on stdin); the worker answers with JSON lines of [`WorkerMessage`].

use crate::results::EvalResult;
use crate::task::{ObsType, ProtocolKind, TaskId};
use serde::{Deserialize, Serialize};

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

/// The perturbation suite a job, a submission (`suite=robustness`) or
/// `d3il eval --suite` asks for (docs/robustness.md): which suite file that
/// is depends on the task and observation type (the evaluator's
/// `robustness::suite_for`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SuiteName {
    /// The robustness track: level 0 and every level of the task's suite.
    Robustness,
}

impl SuiteName {
    /// Every suite name there is.
    pub const ALL: [SuiteName; 1] = [SuiteName::Robustness];

    pub fn as_str(self) -> &'static str {
        match self {
            SuiteName::Robustness => "robustness",
        }
    }

    /// The suite named `name`, or a message naming the ones there are.
    pub fn parse(name: &str) -> Result<SuiteName, String> {
        SuiteName::ALL
            .into_iter()
            .find(|s| s.as_str() == name)
            .ok_or_else(|| {
                let names: Vec<String> = SuiteName::ALL
                    .iter()
                    .map(|s| format!("`{}`", s.as_str()))
                    .collect();
                format!("suite `{name}`: the one suite is {}", names.join(", "))
            })
    }
}

impl std::fmt::Display for SuiteName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for SuiteName {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        SuiteName::parse(s)
    }
}

/// What a job evaluates, and so what the worker answers with
/// ([`Evaluated`]). One variant per mode: a race of a suite, or a suite
/// shard without its suite, cannot be written.
///
/// On the wire (inside the job's object) the tag `kind` and the variant's
/// fields, named as before 0.6.1: `{"kind": "plain"}`, `{"kind": "shard",
/// "shard": {"index": 2, "count": 3}}`, `{"kind": "suite", "suite":
/// "robustness"}`, `{"kind": "suite_shard", "suite": ..., "shard": ...}`,
/// `{"kind": "race", "race": {...}}`. A job written before `kind` existed
/// (optional `shard`, `suite` and `race` fields) reads as the kind its
/// fields make; fields that contradict the tag, or a race with a suite or a
/// shard, are refused with a message saying so.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "KindFields", into = "KindFields")]
pub enum JobKind {
    /// The whole protocol: an [`EvalResult`].
    Plain,
    /// One shard (whole initial states): its [`crate::shard::EvalPart`],
    /// which a server joins with the other shards' (any worker host runs
    /// one).
    Shard(crate::shard::Shard),
    /// The perturbation suite: level 0 (the plain evaluation) and every
    /// level, a [`crate::robustness::RobustnessResult`]. A dry run with a
    /// suite only checks that the suite exists, then runs as a plain one.
    Suite(SuiteName),
    /// The shard's part of level 0 and of every level of the suite
    /// ([`crate::robustness::RobustnessPart`]); a dry run runs the plain shard.
    SuiteShard {
        suite: SuiteName,
        shard: crate::shard::Shard,
    },
    /// A sequential race: the job's policy is A, the race's B; a
    /// [`crate::race::RaceReport`].
    Race(Box<crate::race::RaceJob>),
}

impl JobKind {
    /// The kind of a suite or plain evaluation of all initial states or of
    /// `shard`.
    pub fn of(suite: Option<SuiteName>, shard: Option<crate::shard::Shard>) -> JobKind {
        match (suite, shard) {
            (None, None) => JobKind::Plain,
            (None, Some(shard)) => JobKind::Shard(shard),
            (Some(suite), None) => JobKind::Suite(suite),
            (Some(suite), Some(shard)) => JobKind::SuiteShard { suite, shard },
        }
    }

    /// The shard the job runs, if it runs one.
    pub fn shard(&self) -> Option<crate::shard::Shard> {
        match self {
            JobKind::Shard(shard) | JobKind::SuiteShard { shard, .. } => Some(*shard),
            _ => None,
        }
    }

    /// The suite the job runs, if it runs one.
    pub fn suite(&self) -> Option<SuiteName> {
        match self {
            JobKind::Suite(suite) | JobKind::SuiteShard { suite, .. } => Some(*suite),
            _ => None,
        }
    }

    /// The race, if the job is one.
    pub fn race(&self) -> Option<&crate::race::RaceJob> {
        match self {
            JobKind::Race(race) => Some(race),
            _ => None,
        }
    }

    /// The wire tag (`kind`) of this kind.
    pub fn tag(&self) -> &'static str {
        self.wire_tag().as_str()
    }

    fn wire_tag(&self) -> KindTag {
        match self {
            JobKind::Plain => KindTag::Plain,
            JobKind::Shard(_) => KindTag::Shard,
            JobKind::Suite(_) => KindTag::Suite,
            JobKind::SuiteShard { .. } => KindTag::SuiteShard,
            JobKind::Race(_) => KindTag::Race,
        }
    }
}

/// The wire tag of a [`JobKind`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
enum KindTag {
    Plain,
    Shard,
    Suite,
    SuiteShard,
    Race,
}

impl KindTag {
    fn as_str(self) -> &'static str {
        match self {
            KindTag::Plain => "plain",
            KindTag::Shard => "shard",
            KindTag::Suite => "suite",
            KindTag::SuiteShard => "suite_shard",
            KindTag::Race => "race",
        }
    }
}

/// A [`JobKind`] as its fields sit in a job's JSON object.
#[derive(Serialize, Deserialize)]
struct KindFields {
    /// Absent in jobs written before 0.6.1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    kind: Option<KindTag>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    shard: Option<crate::shard::Shard>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    suite: Option<SuiteName>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    race: Option<Box<crate::race::RaceJob>>,
}

impl From<JobKind> for KindFields {
    fn from(kind: JobKind) -> Self {
        let mut fields = KindFields {
            kind: Some(kind.wire_tag()),
            shard: kind.shard(),
            suite: kind.suite(),
            race: None,
        };
        if let JobKind::Race(race) = kind {
            fields.race = Some(race);
        }
        fields
    }
}

impl TryFrom<KindFields> for JobKind {
    type Error = String;

    fn try_from(f: KindFields) -> Result<Self, String> {
        let tag = match f.kind {
            Some(tag) => tag,
            // Written before 0.6.1: the fields say which kind it is.
            None => match (&f.race, f.suite, f.shard) {
                (Some(_), None, None) => KindTag::Race,
                (Some(_), _, _) => {
                    return Err(
                        "the job has `race` together with `suite` or `shard`: a race runs two \
                         whole plain evaluations; queue the race, or the suite or shard, alone"
                            .into(),
                    )
                }
                (None, suite, shard) => JobKind::of(suite, shard).wire_tag(),
            },
        };
        let present = [
            ("shard", f.shard.is_some()),
            ("suite", f.suite.is_some()),
            ("race", f.race.is_some()),
        ];
        let wanted: &[&str] = match tag {
            KindTag::Plain => &[],
            KindTag::Shard => &["shard"],
            KindTag::Suite => &["suite"],
            KindTag::SuiteShard => &["suite", "shard"],
            KindTag::Race => &["race"],
        };
        for (field, is) in present {
            if is != wanted.contains(&field) {
                let (has, needs) = if is {
                    ("has", "takes no")
                } else {
                    ("lacks", "needs")
                };
                return Err(format!(
                    "a job of kind `{}` {has} `{field}`: that kind {needs} `{field}` \
                     (kinds: plain, shard, suite, suite_shard, race)",
                    tag.as_str()
                ));
            }
        }
        Ok(match (tag, f.suite, f.shard, f.race) {
            (KindTag::Plain, ..) => JobKind::Plain,
            (KindTag::Shard, _, Some(shard), _) => JobKind::Shard(shard),
            (KindTag::Suite, Some(suite), ..) => JobKind::Suite(suite),
            (KindTag::SuiteShard, Some(suite), Some(shard), _) => {
                JobKind::SuiteShard { suite, shard }
            }
            (KindTag::Race, _, _, Some(race)) => JobKind::Race(race),
            _ => unreachable!("the fields were checked against the kind"),
        })
    }
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
mod tests {
    use super::*;

    fn manifest() -> PolicyManifest {
        serde_json::from_str(r#"{"task": "aligning", "history": 5, "horizon": 4, "execute": 4}"#)
            .unwrap()
    }

    #[test]
    fn an_endpoint_secret_travels_in_the_job_but_never_prints() {
        let secret = EndpointSecret::new("s3cret-s3cret-s3cret").unwrap();
        let policy = PolicySource::Remote {
            url: "ws://host:1/".into(),
            secret: Some(secret.clone()),
        };
        let json = serde_json::to_string(&policy).unwrap();
        assert_eq!(
            json,
            r#"{"kind":"remote","url":"ws://host:1/","secret":"s3cret-s3cret-s3cret"}"#
        );
        assert_eq!(serde_json::from_str::<PolicySource>(&json).unwrap(), policy);
        assert!(!format!("{policy:?}").contains("s3cret"), "{policy:?}");
        // Jobs without a secret read and write as before.
        let plain: PolicySource =
            serde_json::from_str(r#"{"kind":"remote","url":"ws://host:1/"}"#).unwrap();
        assert_eq!(
            serde_json::to_string(&plain).unwrap(),
            r#"{"kind":"remote","url":"ws://host:1/"}"#
        );
        let e = EndpointSecret::new("short").unwrap_err();
        assert!(e.contains("5 characters; give 16 to 256"), "{e}");
        let e = EndpointSecret::new("with a space in the middle").unwrap_err();
        assert!(e.contains("' '") && e.contains("no spaces"), "{e}");
    }

    #[test]
    fn manifest_limits_are_stated_once() {
        let m = manifest();
        assert_eq!(m.window, WindowMode::Pad);
        m.validate().unwrap();
        let bad = |f: &dyn Fn(&mut PolicyManifest)| {
            let mut m = manifest();
            f(&mut m);
            m.validate().unwrap_err()
        };
        let e = bad(&|m| m.history = 0);
        assert_eq!(e.field, "history");
        assert!(e.to_string().contains("from 1 to 64"), "{e}");
        assert_eq!(bad(&|m| m.history = 65).field, "history");
        assert_eq!(bad(&|m| m.horizon = 1025).field, "horizon");
        let e = bad(&|m| m.execute = 5);
        assert_eq!(e.field, "execute");
        assert!(e.to_string().contains("horizon H = 4"), "{e}");
        let e = bad(&|m| {
            m.normalisation = Some(Normalisation {
                obs_std: Some(vec![1.0, 0.0]),
                ..Default::default()
            })
        });
        assert_eq!(e.field, "normalisation.obs_std");
        let mut at_max = manifest();
        at_max.history = PolicyManifest::MAX_HISTORY;
        at_max.horizon = PolicyManifest::MAX_HORIZON;
        at_max.execute = PolicyManifest::MAX_HORIZON;
        at_max.validate().unwrap();
    }

    #[test]
    fn manifest_window_mode_parses_and_is_checked_against_the_task() {
        let m: PolicyManifest =
            serde_json::from_str(r#"{"task": "aligning", "history": 5, "window": "grow"}"#)
                .unwrap();
        assert_eq!(m.window, WindowMode::Grow);
        let e = serde_json::from_str::<PolicyManifest>(r#"{"task": "aligning", "window": "grew"}"#)
            .unwrap_err();
        assert!(
            e.to_string().contains("pad") && e.to_string().contains("grow"),
            "{e}"
        );
        let spec = crate::TaskSpec {
            task: TaskId::Aligning,
            obs_dim: 20,
            act_dim: 3,
            max_steps: 400,
            n_behaviours: 2,
        };
        m.validate_for(&spec).unwrap();
        let mut n = m.clone();
        n.normalisation = Some(Normalisation {
            act_mean: Some(vec![0.0; 2]),
            ..Default::default()
        });
        let e = n.validate_for(&spec).unwrap_err();
        assert_eq!(e.field, "normalisation.act_mean");
        assert!(
            e.to_string()
                .contains("has 2 entries but task aligning needs 3"),
            "{e}"
        );
        let other = crate::TaskSpec {
            task: TaskId::Avoiding,
            ..spec
        };
        assert_eq!(m.validate_for(&other).unwrap_err().field, "task");
    }

    /// A job of each kind as JSON, with `kind_fields` beside the job's own.
    fn job_json(kind_fields: &str) -> String {
        let job = Job {
            job_id: "7".into(),
            task: TaskId::Aligning,
            protocol: ProtocolKind::Quick,
            policy: PolicySource::Scripted {
                name: "aligning:inside".into(),
            },
            manifest: manifest(),
            seed: 3,
            limits: Limits::default(),
            assets_dir: "assets".into(),
            dry_run_steps: None,
            build: None,
            kind: JobKind::Plain,
        };
        let mut v = serde_json::to_value(&job).unwrap();
        v.as_object_mut().unwrap().remove("kind");
        let fields: serde_json::Value = serde_json::from_str(kind_fields).unwrap();
        for (k, x) in fields.as_object().unwrap() {
            v[k] = x.clone();
        }
        v.to_string()
    }

    fn race() -> crate::race::RaceJob {
        crate::race::RaceJob {
            policy_b: PolicySource::Scripted {
                name: "aligning:outside".into(),
            },
            manifest_b: manifest(),
            alpha: 0.05,
            delta: None,
            max_live: 4,
        }
    }

    #[test]
    fn each_job_kind_writes_its_tag_and_its_fields_and_reads_back() {
        let shard = crate::shard::Shard { index: 2, count: 3 };
        let suite = SuiteName::Robustness;
        for (kind, fields) in [
            (JobKind::Plain, r#"{"kind":"plain"}"#.to_string()),
            (
                JobKind::Shard(shard),
                r#"{"kind":"shard","shard":{"index":2,"count":3}}"#.to_string(),
            ),
            (
                JobKind::Suite(suite),
                r#"{"kind":"suite","suite":"robustness"}"#.to_string(),
            ),
            (
                JobKind::SuiteShard { suite, shard },
                r#"{"kind":"suite_shard","shard":{"index":2,"count":3},"suite":"robustness"}"#
                    .to_string(),
            ),
            (
                JobKind::Race(Box::new(race())),
                format!(
                    r#"{{"kind":"race","race":{}}}"#,
                    serde_json::to_string(&race()).unwrap()
                ),
            ),
        ] {
            let json = job_json(&fields);
            let job: Job = serde_json::from_str(&json).unwrap();
            assert_eq!(job.kind, kind, "{json}");
            // The kind's fields sit beside the job's own, in this order.
            let written = serde_json::to_string(&job).unwrap();
            let tail = &fields[1..fields.len() - 1];
            assert!(written.contains(tail), "{written} lacks {tail}");
            assert_eq!(serde_json::from_str::<Job>(&written).unwrap(), job);
            assert_eq!(kind.tag(), fields[9..].split('"').next().unwrap());
        }
    }

    /// Jobs written before `kind` existed (by a server or `d3il eval` of
    /// 0.6.0 and earlier) read as the kind their optional fields make.
    #[test]
    fn a_job_written_before_kinds_existed_reads_as_its_fields_say() {
        let shard = crate::shard::Shard { index: 1, count: 2 };
        let race_json = serde_json::to_string(&race()).unwrap();
        for (fields, kind) in [
            ("{}".to_string(), JobKind::Plain),
            (
                r#"{"shard":{"index":1,"count":2}}"#.to_string(),
                JobKind::Shard(shard),
            ),
            (
                r#"{"suite":"robustness"}"#.to_string(),
                JobKind::Suite(SuiteName::Robustness),
            ),
            (
                r#"{"suite":"robustness","shard":{"index":1,"count":2}}"#.to_string(),
                JobKind::SuiteShard {
                    suite: SuiteName::Robustness,
                    shard,
                },
            ),
            (
                format!(r#"{{"race":{race_json}}}"#),
                JobKind::Race(Box::new(race())),
            ),
        ] {
            let job: Job = serde_json::from_str(&job_json(&fields)).unwrap();
            assert_eq!(job.kind, kind, "{fields}");
        }
    }

    #[test]
    fn a_job_whose_fields_contradict_its_kind_is_refused_with_the_reason() {
        let race_json = serde_json::to_string(&race()).unwrap();
        let refused = |fields: &str| {
            serde_json::from_str::<Job>(&job_json(fields))
                .unwrap_err()
                .to_string()
        };
        let e = refused(&format!(r#"{{"race":{race_json},"suite":"robustness"}}"#));
        assert!(e.contains("a race runs two whole plain evaluations"), "{e}");
        let e = refused(r#"{"kind":"plain","shard":{"index":1,"count":2}}"#);
        assert!(
            e.contains("a job of kind `plain` has `shard`: that kind takes no `shard`"),
            "{e}"
        );
        let e = refused(r#"{"kind":"suite_shard","suite":"robustness"}"#);
        assert!(
            e.contains("a job of kind `suite_shard` lacks `shard`: that kind needs `shard`"),
            "{e}"
        );
        let e = refused(r#"{"kind":"robustness"}"#);
        assert!(e.contains("unknown variant `robustness`"), "{e}");
        let e = refused(r#"{"suite":"fragility"}"#);
        assert!(
            e.contains("unknown variant `fragility`, expected `robustness`"),
            "{e}"
        );
    }

    #[test]
    fn suite_names_parse_and_print_as_one_constant() {
        assert_eq!(SuiteName::parse("robustness"), Ok(SuiteName::Robustness));
        assert_eq!(SuiteName::Robustness.to_string(), "robustness");
        assert_eq!(
            serde_json::to_string(&SuiteName::Robustness).unwrap(),
            r#""robustness""#
        );
        assert_eq!(
            "fragility".parse::<SuiteName>().unwrap_err(),
            "suite `fragility`: the one suite is `robustness`"
        );
    }

    #[test]
    fn limits_without_an_extra_ca_keep_their_json() {
        // A job's limits as written before the field existed still parse.
        let old = r#"{"memory_bytes":1,"cpu_seconds":2,"wall_seconds":3,"open_files":4,
            "file_size_bytes":5,"remote_deadline_ms":6,"remote_frame_bytes":7,
            "allow_private_endpoints":true}"#;
        let l: Limits = serde_json::from_str(old).unwrap();
        assert_eq!(l.extra_ca_pem, None);
        assert_eq!(l.remote_frame_bytes, 7);
        // And without a CA nothing new is written.
        let json = serde_json::to_string(&Limits::default()).unwrap();
        assert!(!json.contains("extra_ca_pem"), "{json}");
        let with = Limits {
            extra_ca_pem: Some("-----BEGIN CERTIFICATE-----\n".into()),
            ..Limits::default()
        };
        let back: Limits = serde_json::from_str(&serde_json::to_string(&with).unwrap()).unwrap();
        assert_eq!(back, with);
    }
}
