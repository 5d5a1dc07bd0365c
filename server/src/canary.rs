//! The drift canary on a running server: the server never runs
//! MuJoCo, so at start it runs `d3il verify --json --cached` (a build's
//! report is kept per binary) as a subprocess of its
//! own binary, in the background, and keeps the outcome: the page footer and
//! `/api/v1/build` show it, and every job the pool hands out records the
//! build identity (git commit, physics fingerprint) in its result's manifest.
//! The pool waits for the canary before its first job, so that no result
//! goes without a fingerprint (a few seconds to a minute, once per start).

use d3il_protocol::BuildIdentity;
use std::path::PathBuf;
use std::sync::RwLock;
use std::time::Duration;
use tokio::sync::watch;

#[derive(Debug, Clone)]
pub struct CanaryConfig {
    /// The `d3il` executable (default: the worker executable).
    pub exe: PathBuf,
    /// Run `d3il verify` at start. `d3il serve` does unless told not to;
    /// servers built in code (tests) do not unless asked.
    pub run: bool,
    /// The git commit the binary was built from (the binary knows it).
    pub git_commit: String,
    /// A canary run taking longer is stopped and reported.
    pub timeout: Duration,
    /// This build's physics fingerprint when the caller already knows it
    /// and the canary is not run (`run` false): rows of other builds (the
    /// zoo's among them) say so against it.
    pub fingerprint: Option<String>,
}

impl CanaryConfig {
    pub fn new(exe: PathBuf) -> Self {
        CanaryConfig {
            exe,
            run: false,
            git_commit: "unknown".into(),
            timeout: Duration::from_secs(1800),
            fingerprint: None,
        }
    }
}

/// What the canary said.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
#[serde(tag = "state", rename_all = "snake_case")]
pub enum CanaryState {
    /// Not run on this server.
    Off,
    /// Not run on this server, which was given its build's fingerprint.
    Given {
        fingerprint: String,
    },
    Running,
    /// Every canary outcome matches the committed one.
    Passed {
        fingerprint: String,
    },
    /// This build simulates differently from the committed outcomes.
    Drifted {
        fingerprint: String,
        differences: Vec<String>,
    },
    /// The canary could not run.
    Failed {
        message: String,
    },
}

impl CanaryState {
    pub fn fingerprint(&self) -> Option<&str> {
        match self {
            CanaryState::Passed { fingerprint }
            | CanaryState::Drifted { fingerprint, .. }
            | CanaryState::Given { fingerprint } => Some(fingerprint),
            _ => None,
        }
    }

    /// One line for people (the page footer).
    pub fn summary(&self) -> String {
        match self {
            CanaryState::Off => "drift canary not run on this server".into(),
            CanaryState::Given { fingerprint } => format!(
                "drift canary not run on this server; physics fingerprint {fingerprint} (given)"
            ),
            CanaryState::Running => "drift canary running (d3il verify)".into(),
            CanaryState::Passed { fingerprint } => {
                format!("drift canary passed: physics fingerprint {fingerprint}")
            }
            CanaryState::Drifted {
                fingerprint,
                differences,
            } => format!(
                "DRIFT: this build (physics fingerprint {fingerprint}) simulates differently from the committed canary: {}",
                differences.join("; ")
            ),
            CanaryState::Failed { message } => format!("drift canary failed to run: {message}"),
        }
    }
}

#[derive(Debug)]
pub struct Canary {
    cfg: CanaryConfig,
    state: RwLock<CanaryState>,
    done: watch::Sender<bool>,
}

/// What `d3il verify --json` prints (src/cmd/verify.rs).
#[derive(serde::Deserialize)]
struct VerifyReport {
    fingerprint: String,
    passed: bool,
    entries: Vec<EntryCheck>,
}

#[derive(serde::Deserialize)]
struct EntryCheck {
    entry: String,
    first_difference: Option<String>,
}

impl Canary {
    pub fn new(cfg: CanaryConfig) -> Self {
        let (done, _) = watch::channel(!cfg.run);
        Canary {
            state: RwLock::new(match (cfg.run, &cfg.fingerprint) {
                (true, _) => CanaryState::Running,
                (false, Some(f)) => CanaryState::Given {
                    fingerprint: f.clone(),
                },
                (false, None) => CanaryState::Off,
            }),
            cfg,
            done,
        }
    }

    pub fn state(&self) -> CanaryState {
        self.state.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// This build's physics fingerprint, once the canary has computed it
    /// (the board's rows of other builds say so against it).
    pub fn fingerprint(&self) -> Option<String> {
        self.state().fingerprint().map(str::to_string)
    }

    /// The identity the results of jobs handed out now record.
    pub fn build(&self) -> BuildIdentity {
        BuildIdentity {
            git_commit: self.cfg.git_commit.clone(),
            physics_fingerprint: self.state().fingerprint().map(str::to_string),
        }
    }

    /// Waits until the canary has run (at once when it is not run).
    pub async fn ready(&self) {
        let mut rx = self.done.subscribe();
        let _ = rx.wait_for(|d| *d).await;
    }

    /// Starts `d3il verify --json` in the background.
    pub fn start(self: &std::sync::Arc<Self>) {
        if !self.cfg.run {
            return;
        }
        let me = self.clone();
        tokio::spawn(async move {
            let state = me.run().await;
            match &state {
                CanaryState::Passed { fingerprint } => {
                    tracing::info!("drift canary passed: physics fingerprint {fingerprint}")
                }
                other => tracing::warn!("{}", other.summary()),
            }
            *me.state.write().unwrap_or_else(|e| e.into_inner()) = state;
            me.done.send_replace(true);
        });
    }

    async fn run(&self) -> CanaryState {
        let mut cmd = tokio::process::Command::new(&self.cfg.exe);
        cmd.args(["verify", "--json", "--cached"])
            .env("RUST_BACKTRACE", "0")
            .stdin(std::process::Stdio::null())
            .kill_on_drop(true);
        let out = match tokio::time::timeout(self.cfg.timeout, cmd.output()).await {
            Err(_) => {
                return CanaryState::Failed {
                    message: format!("d3il verify took longer than {:?}", self.cfg.timeout),
                }
            }
            Ok(Err(e)) => {
                return CanaryState::Failed {
                    message: format!("cannot run {}: {e}", self.cfg.exe.display()),
                }
            }
            Ok(Ok(o)) => o,
        };
        match serde_json::from_slice::<VerifyReport>(&out.stdout) {
            Ok(r) if r.passed => CanaryState::Passed {
                fingerprint: r.fingerprint,
            },
            Ok(r) => CanaryState::Drifted {
                fingerprint: r.fingerprint,
                differences: r
                    .entries
                    .into_iter()
                    .filter_map(|e| e.first_difference.map(|d| format!("{}: {d}", e.entry)))
                    .collect(),
            },
            Err(_) => CanaryState::Failed {
                message: String::from_utf8_lossy(&out.stderr)
                    .lines()
                    .last()
                    .unwrap_or("d3il verify printed no report")
                    .to_string(),
            },
        }
    }
}
