//! Parent side: run one `d3il worker` process and turn however it ends into a
//! typed [`Outcome`]. Used by the server's worker pool and by
//! `d3il eval --sandbox`.
//!
//! The worker runs in its own process group (so a kill reaches everything it may
//! have started), dies with its parent thread (PR_SET_PDEATHSIG), gets the job on
//! stdin and answers with JSON lines on stdout, which are read with a byte cap.
//! The wall clock is enforced here; memory and CPU limits are rlimits inside the
//! worker and are recognised here from how it died.

use crate::confine::format_bytes;
use d3il_protocol::{
    exit_code, ErrorKind, EvalResult, Job, Limits, PolicySource, Progress, SandboxMechanism,
    WorkerError, WorkerMessage,
};
use std::io::{BufRead, BufReader, Read, Write};
use std::os::unix::process::CommandExt;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

pub use crate::group::live_group_members;
use crate::group::{has_exited, kill_group, reap, wait_exited, wait_group_gone, ReapGuard, Status};

/// Default cap on what a worker may print on stdout (all lines together). A
/// paper-protocol result with per-rollout records is a few MiB.
pub const DEFAULT_MAX_OUTPUT_BYTES: usize = 64 << 20;
/// How much of the worker's stderr is kept (the end of it, where panics are).
const STDERR_TAIL_BYTES: usize = 64 << 10;

/// How to start a worker.
#[derive(Debug, Clone)]
pub struct WorkerCommand {
    /// The `d3il` binary (or any program speaking the worker protocol).
    pub exe: PathBuf,
    /// Arguments, normally `["worker"]`.
    pub args: Vec<String>,
    /// Wall-clock limit for the whole job; the process group is killed on overrun.
    pub wall_clock: Duration,
    /// Cap on the bytes read from the worker's stdout.
    pub max_output_bytes: usize,
}

impl WorkerCommand {
    /// `exe worker` with the job's wall-clock limit and the default output cap.
    pub fn for_job(exe: impl Into<PathBuf>, job: &Job) -> Self {
        WorkerCommand {
            exe: exe.into(),
            args: vec!["worker".into()],
            wall_clock: Duration::from_secs(job.limits.wall_seconds.max(1)),
            max_output_bytes: DEFAULT_MAX_OUTPUT_BYTES,
        }
    }
}

/// The limits of `evaluations` evaluations in one worker, from those of one:
/// the job's wall clock and CPU time, the supervisor's wall clock (the
/// job's plus its margin) and output cap scaled by `evaluations`; memory,
/// files and the remote endpoint's limits are per evaluation and stay. A
/// server's suite job and `d3il robustness --sandbox` both scale by it.
pub fn suite_limits(
    one: &Limits,
    cmd: &WorkerCommand,
    evaluations: usize,
) -> (Limits, WorkerCommand) {
    let n = evaluations.max(1) as u64;
    let mut limits = one.clone();
    limits.wall_seconds = one.wall_seconds.saturating_mul(n);
    limits.cpu_seconds = one.cpu_seconds.saturating_mul(n);
    let margin = cmd
        .wall_clock
        .saturating_sub(Duration::from_secs(one.wall_seconds));
    let mut cmd = cmd.clone();
    cmd.wall_clock = Duration::from_secs(limits.wall_seconds) + margin;
    cmd.max_output_bytes = cmd.max_output_bytes.saturating_mul(n as usize);
    (limits, cmd)
}

#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Completed(Box<EvalResult>),
    /// The part of one shard (a `JobKind::Shard` job).
    Part(Box<d3il_protocol::shard::EvalPart>),
    /// The robustness document of a `JobKind::Suite` job.
    Robustness(Box<d3il_protocol::robustness::RobustnessResult>),
    /// The part of one shard of a `JobKind::SuiteShard` job.
    SuitePart(Box<d3il_protocol::robustness::RobustnessPart>),
    /// The report of a race job (`JobKind::Race`).
    Race(Box<d3il_protocol::race::RaceReport>),
    Failed(WorkerError),
}

/// Everything known about one worker run.
#[derive(Debug, Clone)]
pub struct WorkerRun {
    pub outcome: Outcome,
    /// The sandbox mechanisms the worker reported (empty if it died before).
    pub mechanisms: Vec<SandboxMechanism>,
    /// The end of the worker's stderr (for operators' logs, not for submitters).
    pub stderr: String,
    /// The worker's pid, which was also its process-group id.
    pub pid: u32,
}

enum Event {
    Message(Box<WorkerMessage>),
    Garbage(String),
    Overflow,
    ReadError(String),
    Eof,
}

fn failed(kind: ErrorKind, message: impl Into<String>) -> Outcome {
    Outcome::Failed(WorkerError {
        kind,
        message: message.into(),
    })
}

/// The PEM of `$D3IL_EXTRA_CA_FILE` for a `wss://` job that does not carry an
/// extra CA already (other jobs are passed on unchanged).
fn extra_ca_for(job: &Job) -> Result<Option<String>, String> {
    match &job.policy {
        PolicySource::Remote { url, .. }
            if job.limits.extra_ca_pem.is_none()
                && url
                    .get(..6)
                    .is_some_and(|s| s.eq_ignore_ascii_case("wss://")) =>
        {
            Limits::extra_ca_from_env()
        }
        _ => Ok(None),
    }
}

/// Run `job` in a worker started with `cmd`. Blocks until the worker has ended
/// and its process group is gone. `on_progress(done, total)` is called on this
/// thread for every progress line.
pub fn run_worker(
    cmd: &WorkerCommand,
    job: &Job,
    on_progress: &mut dyn FnMut(usize, usize),
) -> WorkerRun {
    run_worker_cancellable(cmd, job, on_progress, &AtomicBool::new(false))
}

/// [`run_worker`] that also stops the worker (kills its process group) within
/// about 50 ms of `cancel` becoming true; the outcome is then an `Internal`
/// failure saying so (the caller, who cancelled, knows why).
pub fn run_worker_cancellable(
    cmd: &WorkerCommand,
    job: &Job,
    on_progress: &mut dyn FnMut(usize, usize),
    cancel: &AtomicBool,
) -> WorkerRun {
    run_worker_reporting(
        cmd,
        job,
        &mut |p: &Progress| on_progress(p.rollouts_done, p.rollouts_total),
        cancel,
    )
}

/// [`run_worker_cancellable`] whose `on_progress` gets every progress line
/// whole: the counts and the initial states newly finished in the
/// evaluation's random order ([`Progress::states`]), from which a
/// live confidence sequence of the success rate is computed.
pub fn run_worker_reporting(
    cmd: &WorkerCommand,
    job: &Job,
    on_progress: &mut dyn FnMut(&Progress),
    cancel: &AtomicBool,
) -> WorkerRun {
    // The operator's extra CA for wss:// endpoints travels in the job: the
    // worker may not read the file itself.
    let with_ca;
    let job = match extra_ca_for(job) {
        Ok(Some(pem)) => {
            let mut j = job.clone();
            j.limits.extra_ca_pem = Some(pem);
            with_ca = j;
            &with_ca
        }
        Ok(None) => job,
        Err(e) => {
            return WorkerRun {
                outcome: failed(ErrorKind::Internal, e),
                mechanisms: vec![],
                stderr: String::new(),
                pid: 0,
            }
        }
    };
    let job_json = match serde_json::to_vec(job) {
        Ok(j) => j,
        Err(e) => {
            return WorkerRun {
                outcome: failed(
                    ErrorKind::Internal,
                    format!("could not encode the job: {e}"),
                ),
                mechanisms: vec![],
                stderr: String::new(),
                pid: 0,
            }
        }
    };
    let mut command = Command::new(&cmd.exe);
    command
        .args(&cmd.args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .env_remove(Limits::EXTRA_CA_ENV)
        .process_group(0);
    // SAFETY: the closure only calls prctl, which is async-signal-safe.
    unsafe {
        command.pre_exec(|| {
            // If the thread that spawned us dies (server crash), so do we.
            // run_worker blocks this thread until the worker is reaped, so the
            // signal cannot fire spuriously while the worker is wanted.
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL, 0, 0, 0) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            Ok(())
        });
    }
    let mut child = match command.spawn() {
        Ok(c) => c,
        Err(e) => {
            return WorkerRun {
                outcome: failed(
                    ErrorKind::Internal,
                    format!(
                        "could not start the worker `{}`: {e}; check the server's worker executable setting",
                        cmd.exe.display()
                    ),
                ),
                mechanisms: vec![],
                stderr: String::new(),
                pid: 0,
            }
        }
    };
    let pid = child.id() as libc::pid_t;
    let start = Instant::now();
    let deadline = start + cmd.wall_clock;

    // stdin: the job, then EOF. A worker that dies early makes this fail with
    // EPIPE, which is fine (the Rust runtime ignores SIGPIPE).
    if let Some(mut stdin) = child.stdin.take() {
        std::thread::spawn(move || {
            let _ = stdin.write_all(&job_json);
        });
    }
    let (tx, rx) = mpsc::channel::<Event>();
    if let Some(stdout) = child.stdout.take() {
        let cap = cmd.max_output_bytes;
        std::thread::spawn(move || read_stdout(stdout, cap, tx));
    }
    let stderr_tail = Arc::new(Mutex::new(Tail::default()));
    let (stderr_done_tx, stderr_done) = mpsc::channel::<()>();
    if let Some(stderr) = child.stderr.take() {
        let tail = Arc::clone(&stderr_tail);
        std::thread::spawn(move || {
            read_stderr(stderr, &tail);
            let _ = stderr_done_tx.send(());
        });
    }
    // We reap the child ourselves (wait4, for rusage); std must not.
    drop(child);
    // If anything below unwinds (a panicking on_progress), the worker group is
    // still killed and reaped.
    let mut guard = ReapGuard { pid, armed: true };

    let mut mechanisms = Vec::new();
    let mut progress: Option<(usize, usize)> = None;
    let mut final_msg: Option<Outcome> = None;
    let mut violation: Option<String> = None;
    let mut timed_out = false;
    let mut cancelled = false;
    let mut leader_exited = false;
    loop {
        let now = Instant::now();
        if now >= deadline {
            timed_out = true;
            break;
        }
        if cancel.load(Ordering::Relaxed) {
            cancelled = true;
            break;
        }
        // Wake up regularly to notice the worker's exit even if something it left
        // behind keeps its stdout open.
        match rx.recv_timeout((deadline - now).min(Duration::from_millis(50))) {
            Ok(Event::Message(m)) => match *m {
                WorkerMessage::Sandbox { mechanisms: m } => mechanisms = m,
                WorkerMessage::Progress(p) => {
                    progress = Some((p.rollouts_done, p.rollouts_total));
                    on_progress(&p);
                }
                WorkerMessage::Result(r) => final_msg = Some(Outcome::Completed(r)),
                WorkerMessage::Part(p) => final_msg = Some(Outcome::Part(p)),
                WorkerMessage::Robustness(d) => final_msg = Some(Outcome::Robustness(d)),
                WorkerMessage::SuitePart(p) => final_msg = Some(Outcome::SuitePart(p)),
                WorkerMessage::Race(r) => final_msg = Some(Outcome::Race(r)),
                WorkerMessage::Error(e) => final_msg = Some(Outcome::Failed(e)),
            },
            Ok(Event::Garbage(excerpt)) => {
                violation = Some(format!(
                    "the worker printed output that is not part of the worker protocol: `{excerpt}`"
                ));
                break;
            }
            Ok(Event::Overflow) => {
                violation = Some(format!(
                    "the worker printed more than {} on stdout; results must be smaller",
                    format_bytes(cmd.max_output_bytes as u64)
                ));
                break;
            }
            Ok(Event::ReadError(e)) => {
                violation = Some(format!("reading the worker's output failed: {e}"));
                break;
            }
            Ok(Event::Eof) | Err(RecvTimeoutError::Disconnected) => break,
            Err(RecvTimeoutError::Timeout) => {
                if !leader_exited && has_exited(pid) {
                    // Whatever is still in the pipe stays readable; killing the
                    // rest of the group closes the last writers so EOF comes.
                    leader_exited = true;
                    kill_group(pid);
                }
            }
        }
    }
    if violation.is_some() || timed_out || cancelled {
        kill_group(pid);
    }
    // stdout is closed (or we gave up on it); wait for the process itself, still
    // under the wall clock: a worker can close stdout and keep running.
    if !timed_out && !cancelled && violation.is_none() && !wait_exited(pid, deadline) {
        timed_out = final_msg.is_none();
        kill_group(pid);
    }
    // Anything else in the group (there should be nothing: seccomp forbids
    // process creation) goes now, before the leader is reaped so its pid, which
    // names the group, cannot have been reused. SIGKILL is delivered
    // asynchronously: wait (bounded) until it has taken effect, so that
    // nothing of the worker is running when this returns.
    kill_group(pid);
    wait_group_gone(pid, Duration::from_secs(2));
    let (status, cpu) = reap(pid);
    guard.armed = false;
    // stderr ends when the last writer is gone; give a moment for the tail.
    let _ = stderr_done.recv_timeout(Duration::from_secs(2));
    let stderr = stderr_tail.lock().map(|t| t.text()).unwrap_or_default();

    let ctx = Context {
        job,
        progress,
        elapsed: start.elapsed(),
        cpu,
        wall_clock: cmd.wall_clock,
        stderr: &stderr,
    };
    let outcome = if cancelled {
        failed(ErrorKind::Internal, "the evaluation was cancelled")
    } else if let Some(v) = violation {
        failed(ErrorKind::ProtocolViolation, v)
    } else if let Some(m) = final_msg {
        m
    } else if timed_out {
        failed(
            ErrorKind::WallClock,
            format!(
                "the evaluation did not finish within the {} s wall-clock limit {}{}",
                cmd.wall_clock.as_secs(),
                ctx.phase(),
                match job.policy {
                    PolicySource::Remote { .. } =>
                        "; the endpoint may be hanging or too slow — answer every request within the deadline",
                    _ => "; make the policy faster or ask for a higher limit",
                }
            ),
        )
    } else {
        ctx.classify(status)
    };
    WorkerRun {
        outcome,
        mechanisms,
        stderr,
        pid: pid as u32,
    }
}

struct Context<'a> {
    job: &'a Job,
    progress: Option<(usize, usize)>,
    #[allow(dead_code)]
    elapsed: Duration,
    cpu: Duration,
    #[allow(dead_code)]
    wall_clock: Duration,
    stderr: &'a str,
}

impl Context<'_> {
    /// What the worker was doing, from the last progress line.
    fn phase(&self) -> String {
        match (self.progress, &self.job.policy) {
            (Some((done, total)), _) => {
                format!("while running the rollouts ({done} of {total} done)")
            }
            (None, PolicySource::Onnx { .. }) => "while loading the ONNX file".into(),
            (None, PolicySource::Remote { .. }) => "while connecting to the remote endpoint".into(),
            (None, PolicySource::Scripted { .. }) => "while preparing the evaluation".into(),
        }
    }

    fn out_of_memory_evidence(&self) -> bool {
        let s = self.stderr.to_ascii_lowercase();
        s.contains("memory allocation of")
            || s.contains("could not allocate memory")
            || s.contains("cannot allocate memory")
            || s.contains("out of memory")
            || s.contains("bad_alloc")
    }

    fn memory_limit(&self) -> Outcome {
        failed(
            ErrorKind::MemoryLimit,
            format!(
                "exceeded the {} memory limit {}; make the model smaller or ask for a higher limit",
                format_bytes(self.job.limits.memory_bytes),
                self.phase()
            ),
        )
    }

    fn cpu_limit(&self) -> Outcome {
        failed(
            ErrorKind::CpuLimit,
            format!(
                "used up the {} s CPU-time limit {}; make inference cheaper or ask for a higher limit",
                self.job.limits.cpu_seconds,
                self.phase()
            ),
        )
    }

    /// A panic message from stderr, if the worker panicked.
    fn panic_excerpt(&self) -> Option<String> {
        let i = self.stderr.rfind("panicked at")?;
        let rest = &self.stderr[i..];
        // "panicked at src/x.rs:1:2:\nmessage\nnote: ..."
        let msg: Vec<&str> = rest
            .lines()
            .skip(1)
            .take_while(|l| !l.starts_with("note:") && !l.starts_with("stack backtrace"))
            .collect();
        let msg = msg.join(" ");
        let msg = msg.trim();
        Some(excerpt(if msg.is_empty() { rest } else { msg }, 300))
    }

    fn classify(&self, status: Status) -> Outcome {
        let cpu_limit = self.job.limits.cpu_seconds;
        let cpu_exhausted = cpu_limit > 0 && self.cpu.as_secs() >= cpu_limit;
        match status {
            Status::Signaled(sig) if sig == libc::SIGXCPU => self.cpu_limit(),
            Status::Signaled(libc::SIGKILL) if cpu_exhausted => self.cpu_limit(),
            Status::Signaled(_) | Status::Exited(_) if self.out_of_memory_evidence() => {
                self.memory_limit()
            }
            Status::Signaled(sig) => {
                let hint = match sig {
                    libc::SIGSYS => " (it used a forbidden system call)",
                    libc::SIGKILL => " (killed from outside, e.g. by the kernel's out-of-memory killer)",
                    libc::SIGSEGV if self.stderr.contains("overflowed its stack") => {
                        " (stack overflow: the graph may be too deep)"
                    }
                    libc::SIGXFSZ => " (it tried to write a file larger than allowed)",
                    _ => "",
                };
                failed(
                    ErrorKind::Crashed,
                    format!(
                        "the worker was killed by signal {}{hint} {}; this is recorded for the operators",
                        signal_name(sig),
                        self.phase()
                    ),
                )
            }
            Status::Exited(code) if code == exit_code::BAD_JOB => failed(
                ErrorKind::BadJob,
                format!("the worker rejected the job document (exit code {code}); this is a bug in the server"),
            ),
            Status::Exited(code) if code == exit_code::SANDBOX_FAILED => failed(
                ErrorKind::Internal,
                format!(
                    "the worker could not set up its sandbox (exit code {code}): {}",
                    excerpt(last_line(self.stderr), 300)
                ),
            ),
            Status::Exited(0) => failed(
                ErrorKind::Crashed,
                format!("the worker exited without reporting a result {}", self.phase()),
            ),
            Status::Exited(code) => {
                let what = match self.panic_excerpt() {
                    Some(p) => format!("the worker panicked ({p})"),
                    None => format!("the worker exited with code {code} without a result"),
                };
                failed(ErrorKind::Crashed, format!("{what} {}", self.phase()))
            }
            Status::Unknown => failed(
                ErrorKind::Internal,
                "the worker's exit status could not be collected".to_string(),
            ),
        }
    }
}

fn last_line(s: &str) -> &str {
    s.lines().rev().find(|l| !l.trim().is_empty()).unwrap_or("")
}

fn excerpt(s: &str, max: usize) -> String {
    let s = s.trim();
    if s.len() <= max {
        return s.to_string();
    }
    let mut end = max;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    format!("{}…", &s[..end])
}

fn signal_name(sig: i32) -> String {
    let name = match sig {
        libc::SIGABRT => "SIGABRT",
        libc::SIGBUS => "SIGBUS",
        libc::SIGFPE => "SIGFPE",
        libc::SIGILL => "SIGILL",
        libc::SIGKILL => "SIGKILL",
        libc::SIGSEGV => "SIGSEGV",
        libc::SIGSYS => "SIGSYS",
        libc::SIGTERM => "SIGTERM",
        libc::SIGXCPU => "SIGXCPU",
        libc::SIGXFSZ => "SIGXFSZ",
        libc::SIGPIPE => "SIGPIPE",
        libc::SIGINT => "SIGINT",
        libc::SIGHUP => "SIGHUP",
        _ => return format!("{sig}"),
    };
    format!("{name} ({sig})")
}

/// Read JSON lines, sending each as an event; stops at EOF, at the first line that
/// is not a protocol message, or when more than `cap` bytes were read.
fn read_stdout(stdout: impl Read, cap: usize, tx: mpsc::Sender<Event>) {
    let mut reader = BufReader::with_capacity(64 << 10, stdout);
    let mut total = 0usize;
    let mut line: Vec<u8> = Vec::new();
    loop {
        line.clear();
        // Read one line, but never more than what is left of the cap (+1 so that
        // exceeding it is detected).
        let left = cap.saturating_sub(total) as u64 + 1;
        let n = match (&mut reader).take(left).read_until(b'\n', &mut line) {
            Ok(n) => n,
            Err(e) => {
                let _ = tx.send(Event::ReadError(e.to_string()));
                return;
            }
        };
        if n == 0 {
            let _ = tx.send(Event::Eof);
            return;
        }
        total += n;
        if total > cap {
            let _ = tx.send(Event::Overflow);
            return;
        }
        let text = String::from_utf8_lossy(&line);
        let text = text.trim();
        if text.is_empty() {
            continue;
        }
        let ev = match serde_json::from_str::<WorkerMessage>(text) {
            Ok(m) => Event::Message(Box::new(m)),
            Err(_) => Event::Garbage(excerpt(text, 200)),
        };
        let stop = matches!(ev, Event::Garbage(_));
        if tx.send(ev).is_err() || stop {
            return;
        }
    }
}

/// Keeps the last STDERR_TAIL_BYTES of a stream.
#[derive(Default)]
struct Tail {
    buf: Vec<u8>,
    dropped: bool,
}

impl Tail {
    fn push(&mut self, data: &[u8]) {
        self.buf.extend_from_slice(data);
        if self.buf.len() > STDERR_TAIL_BYTES {
            let cut = self.buf.len() - STDERR_TAIL_BYTES;
            self.buf.drain(..cut);
            self.dropped = true;
        }
    }
    fn text(&self) -> String {
        let s = String::from_utf8_lossy(&self.buf);
        if self.dropped {
            format!("[earlier output dropped]\n{s}")
        } else {
            s.into_owned()
        }
    }
}

fn read_stderr(mut stderr: impl Read, tail: &Mutex<Tail>) {
    let mut buf = [0u8; 8192];
    loop {
        match stderr.read(&mut buf) {
            Ok(0) | Err(_) => return,
            Ok(n) => {
                if let Ok(mut t) = tail.lock() {
                    t.push(&buf[..n]);
                }
            }
        }
    }
}

#[cfg(test)]
#[path = "parent_tests.rs"]
mod tests;
