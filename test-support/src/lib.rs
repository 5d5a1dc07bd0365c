//! Helpers the integration tests of several crates share (a dev-dependency
//! only, never published): where the repository's assets, fixtures and
//! reference rollouts are, the Avoiding job and manifest the worker tests run,
//! limits for policies served on 127.0.0.1, a test PKI made with rcgen and a
//! scratch directory removed on drop.
//!
//! It also re-exports the throw-away PostgreSQL of the store tests ([`pg`]).
//! With the feature `server` it holds the test server harness ([`server`]:
//! the server in-process or as the `d3il` binary, and store seeding).
//!
//! Its dependencies stay minimal (protocol, serde_json, rcgen, pgtemp) so
//! every crate of the workspace can dev-depend on it without a cycle; the
//! `server` feature adds the server, tokio, reqwest and tempfile, for the
//! crates whose tests start a server (the root crate's, and d3il-server's:
//! a dev-dependency cycle, which Cargo allows; the server's own unit tests
//! would see a second copy of the server crate in the harness).
#![forbid(unsafe_code)]

pub use d3il_pgtemp as pg;
pub use d3il_pgtemp::free_port;

pub mod chromium;
pub mod layout;
pub mod listening;
#[cfg(feature = "server")]
pub mod server;

use d3il_protocol::{
    EvalResult, FailureReason, Job, Limits, ObsType, PolicyManifest, PolicySource, ProtocolKind,
    ProtocolManifest, RolloutFailure, RolloutRecord, TaskId,
};
use rcgen::{BasicConstraints, CertificateParams, DnType, IsCa, Issuer, KeyPair, KeyUsagePurpose};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// The repository's root directory (the workspace).
pub fn repo_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .expect("test-support lives inside the repository")
        .to_path_buf()
}

/// `assets/`: MJCF, meshes, context sets, fixtures.
pub fn assets_dir() -> PathBuf {
    repo_dir().join("assets")
}

/// `assets/fixtures/`: the committed ONNX fixtures (scripts/make_fixtures.py).
pub fn fixtures_dir() -> PathBuf {
    assets_dir().join("fixtures")
}

/// The manifest of fixture `stem` (`assets/fixtures/<stem>.json`).
pub fn fixture_manifest(stem: &str) -> PolicyManifest {
    let path = fixtures_dir().join(format!("{stem}.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "fixture manifest {}: {e} (run scripts/make_fixtures.py)",
            path.display()
        )
    });
    serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("fixture manifest {}: {e}", path.display()))
}

/// A reference rollout recorded in the original simulator, by its path under
/// `tests/data/reference-rollouts/` (or under `$D3IL_REFERENCE_ROLLOUTS`).
pub fn reference_rollout(rel: &str) -> Value {
    let dir = std::env::var_os("D3IL_REFERENCE_ROLLOUTS")
        .map(PathBuf::from)
        .unwrap_or_else(|| repo_dir().join("tests/data/reference-rollouts"));
    let path = dir.join(rel);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "reference rollout {} not readable ({e}); set D3IL_REFERENCE_ROLLOUTS to the reference-rollouts directory",
            path.display()
        )
    });
    serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("reference rollout {}: {e}", path.display()))
}

/// The smallest valid Avoiding manifest: state observations, one step of
/// history, horizon and execution.
pub fn avoiding_manifest() -> PolicyManifest {
    PolicyManifest {
        task: TaskId::Avoiding,
        obs_type: ObsType::State,
        history: 1,
        horizon: 1,
        execute: 1,
        normalisation: None,
        window: Default::default(),
    }
}

/// An Avoiding job under the quick protocol (seed 1) with the repository's
/// assets; tests change the fields they care about.
pub fn avoiding_job(policy: PolicySource, limits: Limits) -> Job {
    Job {
        kind: d3il_protocol::JobKind::Plain,
        job_id: "test".into(),
        task: TaskId::Avoiding,
        protocol: ProtocolKind::Quick,
        policy,
        manifest: avoiding_manifest(),
        seed: 1,
        limits,
        assets_dir: assets_dir().display().to_string(),
        dry_run_steps: None,
        build: None,
    }
}

/// The default limits with private endpoints allowed (test policy servers
/// listen on 127.0.0.1) and frames up to 1 MiB.
pub fn loopback_limits() -> Limits {
    Limits {
        remote_frame_bytes: 1 << 20,
        allow_private_endpoints: true,
        ..Limits::default()
    }
}

/// sha256 of `assets/contexts/pushing-v2.json` (the original test contexts).
pub const PUSHING_V2_SHA256: &str =
    "16e158084f5a7940e3dac06b1d91a58a853b5a3fdc6b1a5783dccaa5d21b789f";

/// One synthetic rollout: success, behaviour label, ended unstable.
#[derive(Debug, Clone, Copy, Default)]
pub struct SynthRollout {
    pub success: bool,
    pub label: usize,
    pub unstable: bool,
}

/// A Pushing result on the original contexts (30 states × 16 rollouts) as a
/// worker would store it, with its metrics computed by the metrics crate from
/// `rollout(context, index)`. An unstable rollout is recorded as a failure
/// (`sim_unstable` at step 17) and counted.
pub fn pushing_result(
    protocol: ProtocolKind,
    rollout: impl Fn(usize, usize) -> SynthRollout,
) -> EvalResult {
    let (n_contexts, per) = (30, 16);
    let mut outcomes = vec![];
    let mut rollouts = vec![];
    for c in 0..n_contexts {
        for r in 0..per {
            let x = rollout(c, r);
            let success = x.success && !x.unstable;
            outcomes.push(d3il_metrics::Outcome::new(
                c,
                success,
                Some(&x.label.to_string()),
            ));
            rollouts.push(RolloutRecord {
                context_index: c,
                rollout_index: r,
                success,
                behaviour: serde_json::json!(x.label),
                steps: 400,
                path: None,
                failure: x.unstable.then(|| RolloutFailure {
                    reason: FailureReason::SimUnstable,
                    message: "Nan, Inf or huge value in QACC at DOF 0".into(),
                    step: 17,
                }),
                ending: None,
                trace: None,
            });
        }
    }
    let ev = d3il_metrics::evaluate(
        TaskId::Pushing,
        &outcomes,
        1.0,
        &d3il_metrics::Bootstrap::default(),
    )
    .expect("metrics of a synthetic result");
    EvalResult {
        manifest: ProtocolManifest {
            task_version: "v1".into(),
            initial_states_sha256: PUSHING_V2_SHA256.into(),
            initial_states: "pushing-v2.json".into(),
            n_contexts,
            rollouts_per_context: per,
            max_steps: 400,
            ..test_manifest(TaskId::Pushing, protocol)
        },
        metrics: ev.metrics,
        per_context: ev.per_context,
        rollouts_ended_unstable: rollouts.iter().filter(|r| r.failure.is_some()).count(),
        rollouts,
    }
}

/// Ten Stacking rollouts from two initial states: (initial state, the order in
/// which the boxes registered, whether the full stack stood). The three levels
/// see different data: Stacking-1 the first letters, Stacking-2 the first two,
/// Stacking-3 the full stacks, so each level has its own success and entropies.
pub const STACKING_ROLLOUTS: [(usize, &str, bool); 10] = [
    (0, "gbr", true),
    (0, "rgb", true),
    (0, "gb", false),
    (0, "bg", false),
    (0, "r", false),
    (0, "", false),
    (1, "rbg", true),
    (1, "rbg", true),
    (1, "gr", false),
    (1, "b", false),
];

/// [`STACKING_ROLLOUTS`] as the outcomes d3il-metrics counts (a rollout in
/// which no box registered has no behaviour).
pub fn stacking_outcomes() -> Vec<d3il_metrics::Outcome> {
    STACKING_ROLLOUTS
        .iter()
        .map(|&(c, order, full)| {
            d3il_metrics::Outcome::new(c, full, (!order.is_empty()).then_some(order))
        })
        .collect()
}

/// The protocol manifest of a synthetic result: placeholder hashes and
/// versions, one initial state of one rollout, k = H = E = 1, 10 steps.
/// Tests set the fields they care about with struct update syntax.
pub fn test_manifest(task: TaskId, protocol: ProtocolKind) -> ProtocolManifest {
    ProtocolManifest {
        task,
        task_version: "test".into(),
        obs_type: ObsType::State,
        protocol,
        robot_look: None,
        mjcf_sha256: "m".into(),
        initial_states_sha256: "i".into(),
        initial_states: format!("{}-v1.json", task.slug()),
        mujoco_version: "2.2.2".into(),
        evaluator_version: "0".into(),
        n_contexts: 1,
        rollouts_per_context: 1,
        max_steps: 10,
        policy_sha256: "p".into(),
        history: 1,
        horizon: 1,
        execute: 1,
        seed: 0,
        simulated_once: false,
        build: None,
        perturbation: None,
    }
}

/// A fresh test CA and a server certificate for `names` it signed, written to
/// a directory as `ca.pem`, `server.pem` and `server.key`.
pub struct Pki {
    pub ca_pem: String,
    pub ca_file: PathBuf,
    pub cert: PathBuf,
    pub key: PathBuf,
}

impl Pki {
    pub fn new(dir: &Path, names: &[&str]) -> Pki {
        std::fs::create_dir_all(dir).expect("create the PKI directory");
        let mut ca = CertificateParams::new(Vec::<String>::new()).expect("CA parameters");
        ca.is_ca = IsCa::Ca(BasicConstraints::Unconstrained);
        ca.distinguished_name
            .push(DnType::CommonName, "D3IL test CA");
        ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
        let ca_key = KeyPair::generate().expect("CA key");
        let ca_pem = ca.self_signed(&ca_key).expect("self-signed CA").pem();
        let issuer = Issuer::new(ca, ca_key);
        let key = KeyPair::generate().expect("server key");
        let mut leaf =
            CertificateParams::new(names.iter().map(|s| s.to_string()).collect::<Vec<_>>())
                .expect("server certificate parameters");
        leaf.distinguished_name
            .push(DnType::CommonName, "d3il test policy server");
        let leaf = leaf
            .signed_by(&key, &issuer)
            .expect("signed server certificate");
        let p = Pki {
            ca_pem,
            ca_file: dir.join("ca.pem"),
            cert: dir.join("server.pem"),
            key: dir.join("server.key"),
        };
        std::fs::write(&p.ca_file, &p.ca_pem).expect("write ca.pem");
        std::fs::write(&p.cert, leaf.pem()).expect("write server.pem");
        std::fs::write(&p.key, key.serialize_pem()).expect("write server.key");
        p
    }
}

/// `doc` cut to its first `states` initial states (every level keeps the
/// same ones, with their rollout records), its intervals, drops and scores
/// recomputed: a document as a run on that many states gives it.
pub fn first_states(
    mut doc: d3il_protocol::robustness::RobustnessResult,
    states: usize,
) -> d3il_protocol::robustness::RobustnessResult {
    for r in std::iter::once(&mut doc.control).chain(doc.levels.iter_mut().map(|l| &mut l.result)) {
        r.per_context.truncate(states);
        r.rollouts.retain(|x| x.context_index < states);
        r.manifest.n_contexts = states;
    }
    d3il_metrics::recompute::recompute_robustness(&mut doc).expect("recompute");
    doc
}

/// The standard output, as text, of a command the test needs to have
/// succeeded; otherwise the test fails naming `what`, the exit status and
/// both outputs.
pub fn succeeded(out: &std::process::Output, what: &str) -> String {
    assert!(
        out.status.success(),
        "{what} failed ({}):\nstdout: {}\nstderr: {}",
        out.status,
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The standard error, as text, of a command the test needs to have been
/// refused (a non-zero exit); otherwise the test fails naming `what`.
pub fn refused(out: &std::process::Output, what: &str) -> String {
    assert!(
        !out.status.success(),
        "{what} was accepted:\nstdout: {}\nstderr: {}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A fresh directory under the system temp dir, removed on drop.
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(tag: &str) -> TempDir {
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let p = std::env::temp_dir().join(format!("d3il-{tag}-{}-{nanos}", std::process::id()));
        std::fs::create_dir_all(&p).expect("create temp dir");
        TempDir(p)
    }
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_point_into_the_repository() {
        assert!(assets_dir().is_dir(), "{}", assets_dir().display());
        assert!(fixtures_dir().is_dir(), "{}", fixtures_dir().display());
        let r = reference_rollout("avoiding/route_top_top_top.json");
        assert!(r["policy_actions"].is_array());
    }

    #[test]
    fn avoiding_job_round_trips_and_its_manifest_is_valid_json() {
        let job = avoiding_job(
            PolicySource::Scripted { name: "x".into() },
            loopback_limits(),
        );
        let back: Job = serde_json::from_str(&serde_json::to_string(&job).unwrap()).unwrap();
        assert_eq!(back.manifest, avoiding_manifest());
        assert!(back.limits.allow_private_endpoints);
    }

    #[test]
    fn pki_writes_pem_files_and_temp_dir_is_removed() {
        let t = TempDir::new("pki");
        let p = Pki::new(t.path(), &["127.0.0.1"]);
        for f in [&p.ca_file, &p.cert, &p.key] {
            let text = std::fs::read_to_string(f).unwrap();
            assert!(text.starts_with("-----BEGIN"), "{}", f.display());
        }
        let dir = t.path().to_path_buf();
        drop(t);
        assert!(!dir.exists());
    }
}
