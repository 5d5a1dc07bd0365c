//! The production [`JobRunner`]: `d3il worker` started through the sandbox
//! supervisor (`d3il_sandbox::run_worker`: own process group, dies with the
//! server, wall clock, output cap, rlimits/namespaces/landlock/seccomp inside).

use crate::queue::{JobRunner, RunReport, WorkerProcess};
use d3il_protocol::Progress;
use d3il_protocol::{Evaluated, Job, Limits, SandboxMechanism};
use d3il_sandbox::{run_worker_reporting, Outcome, WorkerCommand};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

pub struct SandboxRunner {
    pub cmd: WorkerCommand,
    /// The limits jobs get, for the sandbox check (admin page).
    pub limits: Limits,
}

impl JobRunner for SandboxRunner {
    fn run(&self, job: &Job, on_progress: &mut dyn FnMut(usize, usize)) -> RunReport {
        self.run_cancellable(
            job,
            &mut |p: &Progress| on_progress(p.rollouts_done, p.rollouts_total),
            &AtomicBool::new(false),
        )
    }

    fn run_cancellable(
        &self,
        job: &Job,
        on_progress: &mut dyn FnMut(&Progress),
        cancel: &AtomicBool,
    ) -> RunReport {
        let run = run_worker_reporting(&self.cmd, job, on_progress, cancel);
        if !run.stderr.trim().is_empty() {
            // Operators' eyes only: stderr may contain anything the policy printed.
            tracing::debug!("worker {} stderr tail: {}", run.pid, run.stderr.trim());
        }
        RunReport {
            outcome: match run.outcome {
                Outcome::Completed(r) => Ok(Evaluated::Result(r)),
                Outcome::Part(p) => Ok(Evaluated::Part(p)),
                Outcome::Robustness(d) => Ok(Evaluated::Robustness(d)),
                Outcome::Race(r) => Ok(Evaluated::Race(r)),
                Outcome::Failed(e) => Err(e),
            },
            mechanisms: run.mechanisms,
        }
    }

    /// `d3il worker --check-sandbox --json --assets DIR`: confines a process
    /// as for an ONNX job and probes it. Its JSON is used even when it exits
    /// non-zero (a probe that was not stopped is shown as such).
    fn check_sandbox(&self, assets_dir: &std::path::Path) -> Result<Vec<SandboxMechanism>, String> {
        let exe = &self.cmd.exe;
        let out = std::process::Command::new(exe)
            .args(&self.cmd.args)
            .args(["--check-sandbox", "--json", "--assets"])
            .arg(assets_dir)
            .args(limits_arg(&self.limits))
            .stdin(std::process::Stdio::null())
            .output()
            .map_err(|e| format!("could not start `{} --check-sandbox`: {e}", exe.display()))?;
        serde_json::from_slice(&out.stdout).map_err(|e| {
            let stderr = String::from_utf8_lossy(&out.stderr);
            let last = stderr
                .lines()
                .rev()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("");
            format!(
                "`{} {} --check-sandbox` ({}) printed no mechanism list ({e}){}",
                exe.display(),
                self.cmd.args.join(" "),
                out.status,
                if last.is_empty() {
                    String::new()
                } else {
                    format!(": {last}")
                }
            )
        })
    }
}

/// `--limits-json` for limits other than the defaults (a worker of an older
/// build, or a test script, is then called exactly as before).
fn limits_arg(limits: &Limits) -> Vec<String> {
    match serde_json::to_string(limits) {
        Ok(j) if *limits != Limits::default() => vec!["--limits-json".into(), j],
        _ => vec![],
    }
}

/// The runner `d3il serve` uses, with the default limits for its sandbox check.
pub fn production_runner(cmd: &WorkerProcess) -> Arc<dyn JobRunner> {
    production_runner_with(cmd, &Limits::default())
}

/// The runner `d3il serve` uses; its sandbox check confines with `limits`.
pub fn production_runner_with(cmd: &WorkerProcess, limits: &Limits) -> Arc<dyn JobRunner> {
    Arc::new(SandboxRunner {
        limits: limits.clone(),
        cmd: WorkerCommand {
            exe: cmd.exe.clone(),
            args: cmd.args.clone(),
            wall_clock: cmd.wall_clock,
            max_output_bytes: cmd.max_output_bytes,
        },
    })
}

/// A counting semaphore for blocking threads (the runner is called on them).
struct Slots {
    free: std::sync::Mutex<usize>,
    freed: std::sync::Condvar,
}

impl Slots {
    fn acquire(&self) -> SlotGuard<'_> {
        let mut free = self.free.lock().unwrap_or_else(|p| p.into_inner());
        while *free == 0 {
            free = self.freed.wait(free).unwrap_or_else(|p| p.into_inner());
        }
        *free -= 1;
        SlotGuard(self)
    }
}

struct SlotGuard<'a>(&'a Slots);

impl Drop for SlotGuard<'_> {
    fn drop(&mut self) {
        *self.0.free.lock().unwrap_or_else(|p| p.into_inner()) += 1;
        self.0.freed.notify_one();
    }
}

/// Every run of the pool's jobs and of submission dry-runs goes through the
/// same slots (as many as the pool has): at most that many worker processes
/// run at once, and a dry-run beyond them queues (its request waits) instead
/// of starting another process (issue 17).
pub struct SharedSlots {
    inner: Arc<dyn JobRunner>,
    slots: Slots,
    capacity: usize,
}

impl SharedSlots {
    /// `workers` slots (at least one, so dry-runs run on a server without
    /// pool slots).
    pub fn wrap(inner: Arc<dyn JobRunner>, workers: usize) -> Arc<dyn JobRunner> {
        let capacity = workers.max(1);
        Arc::new(SharedSlots {
            inner,
            slots: Slots {
                free: std::sync::Mutex::new(capacity),
                freed: std::sync::Condvar::new(),
            },
            capacity,
        })
    }

    pub fn capacity(&self) -> usize {
        self.capacity
    }
}

impl JobRunner for SharedSlots {
    fn run(&self, job: &Job, on_progress: &mut dyn FnMut(usize, usize)) -> RunReport {
        let _slot = self.slots.acquire();
        self.inner.run(job, on_progress)
    }

    fn run_cancellable(
        &self,
        job: &Job,
        on_progress: &mut dyn FnMut(&Progress),
        cancel: &AtomicBool,
    ) -> RunReport {
        let _slot = self.slots.acquire();
        self.inner.run_cancellable(job, on_progress, cancel)
    }

    fn check_sandbox(&self, assets_dir: &std::path::Path) -> Result<Vec<SandboxMechanism>, String> {
        self.inner.check_sandbox(assets_dir)
    }
}
