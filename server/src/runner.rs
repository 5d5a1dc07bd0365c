//! The production [`JobRunner`]: `d3il worker` started through the sandbox
//! supervisor (`d3il_sandbox::run_worker`: own process group, dies with the
//! server, wall clock, output cap, rlimits/namespaces/landlock/seccomp inside).

use crate::queue::{JobRunner, RunReport, WorkerProcess};
use d3il_protocol::Job;
use d3il_sandbox::{run_worker, Outcome, WorkerCommand};
use std::sync::Arc;

pub struct SandboxRunner {
    pub cmd: WorkerCommand,
}

impl JobRunner for SandboxRunner {
    fn run(&self, job: &Job, on_progress: &mut dyn FnMut(usize, usize)) -> RunReport {
        let run = run_worker(&self.cmd, job, on_progress);
        if !run.stderr.trim().is_empty() {
            // Operators' eyes only: stderr may contain anything the policy printed.
            tracing::debug!("worker {} stderr tail: {}", run.pid, run.stderr.trim());
        }
        RunReport {
            outcome: match run.outcome {
                Outcome::Completed(r) => Ok(r),
                Outcome::Failed(e) => Err(e),
            },
            mechanisms: run.mechanisms,
        }
    }
}

/// The runner `d3il serve` uses.
pub fn production_runner(cmd: &WorkerProcess) -> Arc<dyn JobRunner> {
    Arc::new(SandboxRunner {
        cmd: WorkerCommand {
            exe: cmd.exe.clone(),
            args: cmd.args.clone(),
            wall_clock: cmd.wall_clock,
            max_output_bytes: cmd.max_output_bytes,
        },
    })
}
