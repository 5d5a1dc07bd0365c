//! The production [`JobRunner`]: `d3il worker` started through the sandbox.

use crate::queue::{JobRunner, ProcessRunner, WorkerProcess};
use std::sync::Arc;

/// The runner `d3il serve` uses.
pub fn production_runner(cmd: &WorkerProcess) -> Arc<dyn JobRunner> {
    Arc::new(ProcessRunner { cmd: cmd.clone() })
}
