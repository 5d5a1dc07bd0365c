//! Child side: the whole `d3il worker` flow except the evaluation itself, which
//! is passed in (so this crate does not depend on MuJoCo, and the test child can
//! drive hostile "evaluations" through exactly the same code).
//!
//! Protocol (docs/sandbox.md): one JSON [`Job`] on stdin; JSON lines of
//! [`WorkerMessage`] on stdout: `sandbox` first, then `progress`, then one
//! `result` or `error`; exit codes from [`d3il_protocol::exit_code`].

use crate::confine::{self, names};
use crate::endpoint::validate_endpoint;
use d3il_protocol::{
    exit_code, ErrorKind, Evaluated, Job, PolicySource, Progress, SandboxMechanism, WorkerError,
    WorkerMessage,
};
use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::FromRawFd;
use std::path::Path;

/// The largest job document accepted on stdin (jobs reference the ONNX file by
/// path, so they are small).
const MAX_JOB_BYTES: u64 = 1 << 20;

#[derive(Debug, Clone, Default)]
pub struct WorkerOptions {
    /// Mechanism names (see [`confine::names`]) that must be active, or `all`;
    /// if one is not, the worker refuses the job (exit `SANDBOX_FAILED`) instead
    /// of running with weaker confinement.
    pub require: Vec<String>,
}

/// The protocol channel: the original stdout, moved to a private descriptor.
/// fd 1 itself is pointed at stderr, so anything a library prints with printf
/// (MuJoCo warnings, for instance) cannot corrupt the protocol stream.
pub struct ProtocolOut {
    file: File,
}

impl ProtocolOut {
    pub fn take_stdout() -> std::io::Result<ProtocolOut> {
        // SAFETY: plain fd syscalls; the new fd is owned by the File below.
        unsafe {
            let fd = libc::fcntl(1, libc::F_DUPFD_CLOEXEC, 3);
            if fd < 0 {
                return Err(std::io::Error::last_os_error());
            }
            if libc::dup2(2, 1) < 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(ProtocolOut {
                file: File::from_raw_fd(fd),
            })
        }
    }

    pub fn send(&mut self, msg: &WorkerMessage) {
        // A failed write means the parent is gone or stopped reading; there is
        // nobody left to tell, and the parent turns it into an outcome anyway.
        if let Ok(mut line) = serde_json::to_vec(msg) {
            line.push(b'\n');
            let _ = self.file.write_all(&line);
            let _ = self.file.flush();
        }
    }

    fn error(&mut self, kind: ErrorKind, message: impl Into<String>) {
        self.send(&WorkerMessage::Error(WorkerError {
            kind,
            message: message.into(),
        }));
    }
}

/// Read the job from stdin, confine, run `evaluate`, report. Returns the exit code.
pub fn worker_main<F>(opts: &WorkerOptions, evaluate: F) -> i32
where
    F: FnOnce(&Job, &mut dyn FnMut(&Progress)) -> Result<Evaluated, WorkerError>,
{
    let mut out = match ProtocolOut::take_stdout() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("d3il worker: cannot set up the protocol channel: {e}");
            return exit_code::SANDBOX_FAILED;
        }
    };
    let job = match read_job(std::io::stdin().lock()) {
        Ok(j) => j,
        Err(msg) => {
            out.error(ErrorKind::BadJob, msg);
            return exit_code::BAD_JOB;
        }
    };
    // A race job's second policy is read too.
    let policy_files: Vec<&Path> = std::iter::once(&job.policy)
        .chain(job.kind.race().map(|r| &r.policy_b))
        .filter_map(|p| match p {
            PolicySource::Onnx { path, .. } => Some(Path::new(path.as_str())),
            _ => None,
        })
        .collect();
    let mechanisms = match confine::confine(&job, &policy_files) {
        Ok(m) => m,
        Err(e) => {
            eprintln!("d3il worker: sandbox setup failed: {e}");
            let kind = if matches!(e, confine::SandboxError::PolicyFile { .. }) {
                ErrorKind::BadModel
            } else {
                ErrorKind::Internal
            };
            out.error(kind, format!("the sandbox could not be set up: {e}"));
            return if kind == ErrorKind::BadModel {
                exit_code::JOB_FAILED
            } else {
                exit_code::SANDBOX_FAILED
            };
        }
    };
    for m in &mechanisms {
        eprintln!(
            "d3il worker: sandbox {:<18} {:<8} {}",
            m.name,
            if m.active { "active" } else { "INACTIVE" },
            m.detail
        );
    }
    out.send(&WorkerMessage::Sandbox {
        mechanisms: mechanisms.clone(),
    });
    if let Some(missing) = missing_required(&opts.require, &mechanisms) {
        out.error(ErrorKind::Internal, missing);
        return exit_code::SANDBOX_FAILED;
    }
    for policy in std::iter::once(&job.policy).chain(job.kind.race().map(|r| &r.policy_b)) {
        if let PolicySource::Remote { url, .. } = policy {
            if let Err(e) = validate_endpoint(url, job.limits.allow_private_endpoints) {
                out.send(&WorkerMessage::Error(e.into()));
                return exit_code::JOB_FAILED;
            }
        }
    }
    let result = {
        let mut progress = |p: &Progress| out.send(&WorkerMessage::Progress(p.clone()));
        evaluate(&job, &mut progress)
    };
    match result {
        Ok(Evaluated::Result(r)) => {
            out.send(&WorkerMessage::Result(r));
            exit_code::OK
        }
        Ok(Evaluated::Part(p)) => {
            out.send(&WorkerMessage::Part(p));
            exit_code::OK
        }
        Ok(Evaluated::Robustness(doc)) => {
            out.send(&WorkerMessage::Robustness(doc));
            exit_code::OK
        }
        Ok(Evaluated::SuitePart(p)) => {
            out.send(&WorkerMessage::SuitePart(p));
            exit_code::OK
        }
        Ok(Evaluated::Race(report)) => {
            out.send(&WorkerMessage::Race(report));
            exit_code::OK
        }
        Err(e) => {
            out.send(&WorkerMessage::Error(e));
            exit_code::JOB_FAILED
        }
    }
}

fn read_job(stdin: impl Read) -> Result<Job, String> {
    let mut buf = Vec::new();
    stdin
        .take(MAX_JOB_BYTES + 1)
        .read_to_end(&mut buf)
        .map_err(|e| format!("could not read the job from stdin: {e}"))?;
    if buf.len() as u64 > MAX_JOB_BYTES {
        return Err(format!(
            "the job document is larger than {MAX_JOB_BYTES} bytes; jobs reference the policy file by path"
        ));
    }
    serde_json::from_slice(&buf).map_err(|e| format!("the job document is not a valid job: {e}"))
}

fn missing_required(require: &[String], mechanisms: &[SandboxMechanism]) -> Option<String> {
    let all = require.iter().any(|r| r == "all");
    let bad: Vec<String> = mechanisms
        .iter()
        .filter(|m| !m.active && (all || require.iter().any(|r| r == &m.name)))
        // "Not used" (remote policies have no network namespace) is by design.
        .filter(|m| !m.detail.starts_with("not used"))
        .map(|m| format!("{} ({})", m.name, m.detail))
        .collect();
    let unknown: Vec<&String> = require
        .iter()
        .filter(|r| *r != "all" && !names::ALL.contains(&r.as_str()))
        .collect();
    if !unknown.is_empty() {
        return Some(format!(
            "unknown sandbox mechanism(s) required: {unknown:?}; known: {:?}",
            names::ALL
        ));
    }
    if bad.is_empty() {
        None
    } else {
        Some(format!(
            "required sandbox mechanism(s) not active on this host: {}",
            bad.join("; ")
        ))
    }
}

/// `d3il worker --check-sandbox`: confine this process as for an ONNX job (the
/// strictest case), then probe that the mechanisms really bite. Returns the
/// mechanisms plus one `probe:` entry per check. The process stays confined:
/// call this only right before exiting.
pub fn check_sandbox(assets_dir: &Path) -> Result<Vec<SandboxMechanism>, confine::SandboxError> {
    check_sandbox_with(assets_dir, &Default::default())
}

/// [`check_sandbox`] with the limits a server was configured with, so the
/// report (its `rlimits` detail) shows the limits jobs actually get.
pub fn check_sandbox_with(
    assets_dir: &Path,
    limits: &d3il_protocol::Limits,
) -> Result<Vec<SandboxMechanism>, confine::SandboxError> {
    let job = Job {
        kind: d3il_protocol::JobKind::Plain,
        job_id: "check-sandbox".into(),
        task: d3il_protocol::TaskId::Avoiding,
        protocol: Default::default(),
        policy: PolicySource::Scripted {
            name: "check-sandbox".into(),
        },
        manifest: d3il_protocol::PolicyManifest {
            task: d3il_protocol::TaskId::Avoiding,
            obs_type: d3il_protocol::ObsType::State,
            history: 1,
            horizon: 1,
            execute: 1,
            normalisation: None,
            window: Default::default(),
        },
        seed: 0,
        limits: limits.clone(),
        assets_dir: assets_dir.display().to_string(),
        dry_run_steps: None,
        build: None,
    };
    let mut mechanisms = confine::confine(&job, &[])?;
    mechanisms.extend(crate::selftest::probes(assets_dir));
    Ok(mechanisms)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn m(name: &str, active: bool, detail: &str) -> SandboxMechanism {
        SandboxMechanism {
            name: name.into(),
            active,
            detail: detail.into(),
        }
    }

    #[test]
    fn required_mechanisms_are_checked() {
        let ms = vec![
            m("seccomp", true, "x"),
            m("landlock-net", false, "kernel too old"),
            m("network-namespace", false, "not used: remote"),
        ];
        assert_eq!(missing_required(&[], &ms), None);
        assert_eq!(missing_required(&["seccomp".into()], &ms), None);
        let e = missing_required(&["all".into()], &ms).unwrap();
        assert!(e.contains("landlock-net (kernel too old)"), "{e}");
        assert!(!e.contains("network-namespace"), "{e}");
        let e = missing_required(&["selinux".into()], &ms).unwrap();
        assert!(e.contains("unknown"), "{e}");
    }

    #[test]
    fn job_reading_rejects_garbage_and_huge_documents() {
        let e = read_job(&b"{not json"[..]).unwrap_err();
        assert!(e.contains("not a valid job"), "{e}");
        let huge = vec![b' '; (MAX_JOB_BYTES + 10) as usize];
        let e = read_job(&huge[..]).unwrap_err();
        assert!(e.contains("larger than"), "{e}");
    }
}
