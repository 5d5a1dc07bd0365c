//! The fidelity report behind `/fidelity`: the server never runs
//! MuJoCo, so at start it runs `d3il fidelity --format json` as a
//! subprocess of its own binary, in the background: one process, one
//! thread (`RAYON_NUM_THREADS=1`), at the lowest priority (`nice -n 19`),
//! stopped after a timeout, outside the worker slots, so it never holds up
//! an evaluation. The JSON is cached on disk keyed by the binary (sha256
//! of the executable) and the report's mode; a restart of the same build
//! shows it at once. A full report comes after the quick one, which is
//! shown (labelled) meanwhile; until there is one the page says it is being
//! computed.

use d3il_protocol::fidelity::{FidelityMode, FidelityReport};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use std::sync::{Arc, RwLock};
use std::time::Duration;

/// How the report is made.
#[derive(Debug, Clone)]
pub struct FidelityConfig {
    /// The `d3il` executable (default: the worker executable).
    pub exe: PathBuf,
    /// Full or quick report; None: not computed (the page says so). `d3il
    /// serve` computes the full one unless told otherwise (`--fidelity`);
    /// servers built in code (tests) compute none unless asked.
    pub mode: Option<FidelityMode>,
    /// Niceness of the subprocess (through `nice`, when installed).
    pub nice: i32,
    /// A run taking longer is stopped and reported.
    pub timeout: Duration,
    /// Where reports are cached (default: `fidelity/` in the store's data
    /// directory).
    pub dir: Option<PathBuf>,
}

impl FidelityConfig {
    pub fn new(exe: PathBuf) -> Self {
        FidelityConfig {
            exe,
            mode: None,
            nice: 19,
            timeout: Duration::from_secs(4 * 3600),
            dir: None,
        }
    }
}

/// What `/fidelity` can show.
#[derive(Debug, Clone)]
pub enum FidelityState {
    /// Not computed on this server (`--fidelity off`).
    Off,
    /// Being computed since this Unix time; nothing to show yet.
    Computing {
        since: i64,
        mode: FidelityMode,
    },
    /// A report (its `mode` says which), and what comes after it: the full
    /// report replaces a quick one shown while it is computed.
    Ready {
        report: Arc<FidelityReport>,
        next: Next,
    },
    Failed(String),
}

/// After a shown report.
#[derive(Debug, Clone, PartialEq)]
pub enum Next {
    /// It is the one asked for.
    Nothing,
    /// The full report is being computed since this Unix time.
    Full { since: i64 },
    /// The full report could not be computed; the quick one stays.
    FullFailed(String),
}

pub struct FidelityReports {
    cfg: FidelityConfig,
    dir: PathBuf,
    state: RwLock<FidelityState>,
}

fn now() -> i64 {
    std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs() as i64)
        .unwrap_or(0)
}

/// sha256 of a file, streamed: what the per-binary caches (fidelity reports
/// here, `d3il verify`'s report and fingerprint) are keyed by.
pub fn file_sha256(path: &Path) -> std::io::Result<String> {
    let mut f = std::fs::File::open(path)?;
    let mut h = Sha256::new();
    std::io::copy(&mut f, &mut h)?;
    Ok(hex::encode(h.finalize()))
}

impl FidelityReports {
    pub fn new(cfg: FidelityConfig, data_dir: &Path) -> Self {
        let dir = cfg.dir.clone().unwrap_or_else(|| data_dir.join("fidelity"));
        let state = match cfg.mode {
            None => FidelityState::Off,
            Some(mode) => FidelityState::Computing { since: now(), mode },
        };
        FidelityReports {
            cfg,
            dir,
            state: RwLock::new(state),
        }
    }

    pub fn state(&self) -> FidelityState {
        self.state.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    fn set(&self, s: FidelityState) {
        *self.state.write().unwrap_or_else(|e| e.into_inner()) = s;
    }

    /// Starts the background computation (or reads the cached report). For
    /// a full report on a build that has none cached, the quick one comes
    /// first (read from the cache or computed, minutes instead of the full
    /// one's tens of minutes on two cores) and is shown, labelled, until the
    /// full one replaces it.
    pub fn start(self: &Arc<Self>) {
        let Some(mode) = self.cfg.mode else { return };
        let me = self.clone();
        tokio::spawn(async move {
            let key = match me.key().await {
                Ok(k) => k,
                Err(e) => return me.set(FidelityState::Failed(e)),
            };
            if mode == FidelityMode::Full && me.cached(&key, mode).await.is_none() {
                me.set(FidelityState::Computing {
                    since: now(),
                    mode: FidelityMode::Quick,
                });
                match me.load_or_compute(&key, FidelityMode::Quick).await {
                    Ok(r) => me.set(FidelityState::Ready {
                        report: Arc::new(r),
                        next: Next::Full { since: now() },
                    }),
                    Err(e) => {
                        tracing::warn!("quick fidelity report: {e}");
                        me.set(FidelityState::Computing {
                            since: now(),
                            mode: FidelityMode::Full,
                        });
                    }
                }
            }
            let state = match (me.load_or_compute(&key, mode).await, me.state()) {
                (Ok(r), _) => FidelityState::Ready {
                    report: Arc::new(r),
                    next: Next::Nothing,
                },
                (Err(e), FidelityState::Ready { report, .. }) => {
                    tracing::warn!("full fidelity report: {e}");
                    FidelityState::Ready {
                        report,
                        next: Next::FullFailed(e),
                    }
                }
                (Err(e), _) => {
                    tracing::warn!("fidelity report: {e}");
                    FidelityState::Failed(e)
                }
            };
            me.set(state);
        });
    }

    /// The cache key of this build: the executable's sha256.
    async fn key(&self) -> Result<String, String> {
        let exe = self.cfg.exe.clone();
        tokio::task::spawn_blocking(move || file_sha256(&exe))
            .await
            .map_err(|e| e.to_string())?
            .map_err(|e| format!("cannot read {}: {e}", self.cfg.exe.display()))
    }

    fn path(&self, key: &str, mode: FidelityMode) -> PathBuf {
        self.dir
            .join(format!("{}-{}.json", &key[..16], mode.as_str()))
    }

    async fn cached(&self, key: &str, mode: FidelityMode) -> Option<FidelityReport> {
        let bytes = tokio::fs::read(self.path(key, mode)).await.ok()?;
        serde_json::from_slice::<FidelityReport>(&bytes).ok()
    }

    async fn load_or_compute(
        &self,
        key: &str,
        mode: FidelityMode,
    ) -> Result<FidelityReport, String> {
        if let Some(r) = self.cached(key, mode).await {
            return Ok(r);
        }
        let path = self.path(key, mode);
        tokio::fs::create_dir_all(&self.dir)
            .await
            .map_err(|e| format!("cannot create {}: {e}", self.dir.display()))?;
        self.run(mode, &path).await?;
        let bytes = tokio::fs::read(&path)
            .await
            .map_err(|e| format!("reading {}: {e}", path.display()))?;
        serde_json::from_slice(&bytes)
            .map_err(|e| format!("{} is not a report: {e}", path.display()))
    }

    /// `[nice -n N] d3il fidelity --format json --out PATH [--quick]`.
    async fn run(&self, mode: FidelityMode, out: &Path) -> Result<(), String> {
        let nice = Path::new("/usr/bin/nice");
        let mut cmd = if self.cfg.nice != 0 && nice.exists() {
            let mut c = tokio::process::Command::new(nice);
            c.arg("-n")
                .arg(self.cfg.nice.to_string())
                .arg(&self.cfg.exe);
            c
        } else {
            tokio::process::Command::new(&self.cfg.exe)
        };
        cmd.args([
            "fidelity",
            "--format",
            "json",
            "--exit-with-parent",
            "--out",
        ])
        .arg(out);
        if mode == FidelityMode::Quick {
            cmd.arg("--quick");
        }
        cmd.env("RAYON_NUM_THREADS", "1")
            .env("RUST_BACKTRACE", "0")
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .kill_on_drop(true);
        let child = cmd
            .spawn()
            .map_err(|e| format!("cannot start {}: {e}", self.cfg.exe.display()))?;
        match tokio::time::timeout(self.cfg.timeout, child.wait_with_output()).await {
            Err(_) => Err(format!(
                "d3il fidelity took longer than {} s and was stopped",
                self.cfg.timeout.as_secs()
            )),
            Ok(Err(e)) => Err(format!("d3il fidelity: {e}")),
            Ok(Ok(o)) if o.status.success() => Ok(()),
            Ok(Ok(o)) => {
                let err = String::from_utf8_lossy(&o.stderr);
                let tail: String = err
                    .lines()
                    .rev()
                    .take(5)
                    .collect::<Vec<_>>()
                    .into_iter()
                    .rev()
                    .collect::<Vec<_>>()
                    .join("\n");
                Err(format!("d3il fidelity failed ({}): {tail}", o.status))
            }
        }
    }
}
