//! The production [`JobRunner`]: `d3il worker` started through the sandbox
//! supervisor (`d3il_sandbox::run_worker`: own process group, dies with the
//! server, wall clock, output cap, rlimits/namespaces/landlock/seccomp inside).

use crate::queue::{JobRunner, RunReport, WorkerProcess};
use d3il_protocol::Progress;
use d3il_protocol::{Evaluated, Job, Limits, SandboxMechanism};
use d3il_sandbox::{run_worker_reporting, suite_limits, Outcome, WorkerCommand};
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
        let (job, cmd) = scaled_for_suite(job, &self.cmd);
        let run = run_worker_reporting(&cmd, &job, on_progress, cancel);
        if !run.stderr.trim().is_empty() {
            // Operators' eyes only: stderr may contain anything the policy printed.
            tracing::debug!("worker {} stderr tail: {}", run.pid, run.stderr.trim());
        }
        RunReport {
            outcome: match run.outcome {
                Outcome::Completed(r) => Ok(Evaluated::Result(r)),
                Outcome::Part(p) => Ok(Evaluated::Part(p)),
                Outcome::Robustness(d) => Ok(Evaluated::Robustness(d)),
                Outcome::SuitePart(p) => Ok(Evaluated::SuitePart(p)),
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

/// The job and worker command a job runs with: a suite job (`JobKind::Suite`)
/// runs level 0 and every level of its suite, each a whole evaluation (or,
/// for a shard, each the shard's block of it), in one worker, so its wall
/// clock, CPU time and output cap are those of one evaluation (or shard)
/// times the number of evaluations (`d3il_sandbox::suite_limits`); any
/// other job runs as given.
fn scaled_for_suite(job: &Job, cmd: &WorkerCommand) -> (Job, WorkerCommand) {
    let evaluations = match job.kind.suite() {
        Some(_) => crate::intake::suite_evaluations(
            std::path::Path::new(&job.assets_dir),
            job.task,
            job.manifest.obs_type,
        )
        .unwrap_or(1),
        None => 1,
    };
    let (limits, cmd) = suite_limits(&job.limits, cmd, evaluations);
    let mut job = job.clone();
    job.limits = limits;
    (job, cmd)
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
/// of starting another process.
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

#[cfg(test)]
mod tests {
    use super::*;

    /// A suite job runs level 0 and every level in one worker: the limits
    /// meant for one evaluation, which would stop it after the first
    /// evaluations' worth of time or output, grow with the suite.
    #[test]
    fn a_suite_job_gets_the_limits_of_all_its_evaluations() {
        let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../assets");
        let one = Limits::default();
        let cmd = WorkerCommand {
            exe: "d3il".into(),
            args: vec!["worker".into()],
            wall_clock: std::time::Duration::from_secs(one.wall_seconds + 30),
            max_output_bytes: d3il_sandbox::DEFAULT_MAX_OUTPUT_BYTES,
        };
        // Aligning's state suite v2: level 0 and 3 + 3 + 3 + 4 levels.
        let n = crate::intake::suite_evaluations(
            &assets,
            d3il_protocol::TaskId::Aligning,
            d3il_protocol::ObsType::State,
        )
        .unwrap();
        assert_eq!(n, 14);
        let (limits, scaled) = suite_limits(&one, &cmd, n);
        assert_eq!(limits.wall_seconds, 14 * one.wall_seconds);
        assert_eq!(limits.cpu_seconds, 14 * one.cpu_seconds);
        assert_eq!(limits.memory_bytes, one.memory_bytes);
        assert_eq!(
            scaled.wall_clock,
            std::time::Duration::from_secs(14 * one.wall_seconds + 30)
        );
        assert_eq!(scaled.max_output_bytes, 14 * cmd.max_output_bytes);
        // An evaluation that needs 90 % of one evaluation's wall clock, 14
        // times over, fits the suite job's limit but not one evaluation's.
        let need = 14 * one.wall_seconds * 9 / 10;
        assert!(need <= limits.wall_seconds && need > one.wall_seconds);
        // Image policies: Aligning's image suite, 1 + 3 × 5 evaluations.
        let image = crate::intake::suite_evaluations(
            &assets,
            d3il_protocol::TaskId::Aligning,
            d3il_protocol::ObsType::Image,
        );
        assert_eq!(image, Some(17));
        // Through the runner: a suite job of Aligning (state) gets 14 times
        // the limits; a plain job runs as given.
        let mut job = d3il_test_support::avoiding_job(
            d3il_protocol::PolicySource::Scripted {
                name: "aligning:inside".into(),
            },
            one.clone(),
        );
        job.task = d3il_protocol::TaskId::Aligning;
        job.manifest.task = job.task;
        let (plain, plain_cmd) = scaled_for_suite(&job, &cmd);
        assert_eq!(plain.limits, one);
        assert_eq!(plain_cmd.wall_clock, cmd.wall_clock);
        job.kind = d3il_protocol::JobKind::Suite(d3il_protocol::SuiteName::Robustness);
        let (suite_job, suite_cmd) = scaled_for_suite(&job, &cmd);
        assert_eq!(suite_job.limits, limits);
        assert_eq!(suite_cmd.wall_clock, scaled.wall_clock);
        // A shard of a suite job runs level 0 and every level too (on its
        // block of initial states): the same limits, as a plain shard gets
        // those of a plain job.
        job.kind = d3il_protocol::JobKind::SuiteShard {
            suite: d3il_protocol::SuiteName::Robustness,
            shard: d3il_protocol::shard::Shard { index: 2, count: 2 },
        };
        let (shard_job, shard_cmd) = scaled_for_suite(&job, &cmd);
        assert_eq!(shard_job.limits, limits);
        assert_eq!(shard_cmd.wall_clock, scaled.wall_clock);
    }
}
