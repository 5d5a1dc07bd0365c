//! The sandbox mechanisms in force on this host, for the admin page:
//! what `d3il worker --check-sandbox --json` reports, including mechanisms the
//! kernel lacks. Checked once per server process (at start, or by the first
//! admin page view if that comes first).

use crate::queue::JobRunner;
use d3il_protocol::SandboxMechanism;
use std::path::PathBuf;
use std::sync::Arc;

/// The outcome of one `--check-sandbox` run.
#[derive(Debug, Clone, PartialEq)]
pub struct SandboxCheck {
    /// Unix seconds.
    pub checked_at: i64,
    /// The mechanisms and probes, or why the check could not run.
    pub result: Result<Vec<SandboxMechanism>, String>,
}

impl SandboxCheck {
    /// Mechanisms (not probes) the worker reported as not in force.
    pub fn missing(&self) -> Vec<&SandboxMechanism> {
        match &self.result {
            Ok(ms) => ms.iter().filter(|m| !m.active).collect(),
            Err(_) => vec![],
        }
    }
}

pub struct SandboxStatus {
    runner: Arc<dyn JobRunner>,
    assets_dir: PathBuf,
    cell: tokio::sync::OnceCell<SandboxCheck>,
}

impl SandboxStatus {
    pub fn new(runner: Arc<dyn JobRunner>, assets_dir: PathBuf) -> Self {
        SandboxStatus {
            runner,
            assets_dir,
            cell: tokio::sync::OnceCell::new(),
        }
    }

    /// The check, run on first use (on a blocking thread: it starts a process).
    pub async fn get(&self) -> &SandboxCheck {
        self.cell
            .get_or_init(|| async {
                let runner = self.runner.clone();
                let assets = self.assets_dir.clone();
                let result = tokio::task::spawn_blocking(move || runner.check_sandbox(&assets))
                    .await
                    .unwrap_or_else(|e| Err(format!("the sandbox check panicked: {e}")));
                if let Ok(ms) = &result {
                    for m in ms.iter().filter(|m| !m.active) {
                        tracing::warn!("sandbox: {} is NOT in force: {}", m.name, m.detail);
                    }
                }
                SandboxCheck {
                    checked_at: std::time::SystemTime::now()
                        .duration_since(std::time::UNIX_EPOCH)
                        .map(|d| d.as_secs() as i64)
                        .unwrap_or(0),
                    result,
                }
            })
            .await
    }
}
