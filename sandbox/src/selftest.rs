//! Deliberately misbehaving worker "evaluations", and sandbox probes.
//!
//! These drive the real worker flow ([`crate::worker_main`]) and the real parent
//! ([`crate::run_worker`]) through every way a worker can end, without needing
//! MuJoCo or a submission: `d3il worker --self-test <mode>` and the test binary
//! `d3il-sandbox-selftest <mode>` both use them. They are hidden from `--help`
//! and produce results clearly marked as self-tests.

use d3il_protocol::{
    ErrorKind, Estimate, EvalResult, Job, Metrics, ProtocolManifest, SandboxMechanism, WorkerError,
};
use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::Path;
use std::time::Duration;

/// Modes that must run before the normal worker flow (they misbehave on the
/// protocol channel itself, or set up something before confinement). Returns
/// Some(exit code) if the mode was handled completely.
pub fn before_worker(mode: &str) -> Option<i32> {
    match mode {
        // Not the protocol at all.
        "garbage" => {
            // Consume the job so the parent's writer is not the one to fail.
            let _ = std::io::stdin().read_to_end(&mut Vec::new());
            println!("Hello! I am definitely not a JSON line.");
            let _ = std::io::stdout().flush();
            Some(0)
        }
        // More output than the parent's cap, as one endless line.
        "flood" => {
            let chunk = vec![b'x'; 1 << 16];
            let mut out = std::io::stdout().lock();
            loop {
                if out.write_all(&chunk).is_err() {
                    return Some(1);
                }
            }
        }
        // Nothing at all, exit 0.
        "silent-exit" => {
            let _ = std::io::stdin().read_to_end(&mut Vec::new());
            Some(0)
        }
        // A grandchild in the worker's process group that outlives the worker:
        // the parent must kill it (forked before confinement forbids it).
        "orphan" => {
            // SAFETY: the child only calls async-signal-safe pause/_exit.
            let pid = unsafe { libc::fork() };
            if pid == 0 {
                loop {
                    // SAFETY: pause has no arguments.
                    unsafe { libc::pause() };
                }
            }
            let _ = std::io::stdin().read_to_end(&mut Vec::new());
            Some(0)
        }
        _ => None,
    }
}

/// The "evaluation" of a self-test mode, run after confinement inside
/// [`crate::worker_main`].
pub fn evaluate(
    mode: &str,
    job: &Job,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<EvalResult, WorkerError> {
    let (mode, arg) = mode.split_once(':').unwrap_or((mode, ""));
    match mode {
        "ok" => {
            progress(0, 2);
            progress(1, 2);
            progress(2, 2);
            Ok(fake_result(job))
        }
        // Library noise on fd 1 must not reach the protocol channel.
        "printf" => {
            println!("WARNING: a C library printing to stdout");
            // SAFETY: a C-level write to fd 1, as MuJoCo's printf would do.
            unsafe { libc::write(1, b"raw write to fd 1\n".as_ptr().cast(), 18) };
            Ok(fake_result(job))
        }
        "alloc" => alloc_forever(),
        "progress-then-alloc" => {
            progress(3, 10);
            alloc_forever()
        }
        "spin" => {
            let mut x = 0u64;
            loop {
                x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
            }
        }
        "sleep" => loop {
            std::thread::sleep(Duration::from_secs(3600));
        },
        "panic" => panic!("self-test panic: the ONNX graph had a node of type Foo"),
        "signal" => {
            let sig: i32 = arg.parse().unwrap_or(libc::SIGSEGV);
            // SAFETY: raising a signal at ourselves.
            unsafe { libc::raise(sig) };
            Err(internal(format!("signal {sig} did not kill the worker")))
        }
        // A real invalid memory access (raise(SIGSEGV) would be swallowed by the
        // Rust runtime's stack-overflow handler).
        "segfault" => {
            // SAFETY: deliberately unsafe: this is the crash being tested.
            unsafe { std::ptr::write_volatile(std::ptr::null_mut::<u64>(), 1) };
            Err(internal("the null write did not crash".into()))
        }
        "threads" => {
            let handles: Vec<_> = (0..4u64)
                .map(|i| std::thread::spawn(move || (0..1000u64).map(|x| x * i).sum::<u64>()))
                .collect();
            let mut sum = 0;
            for h in handles {
                sum += h
                    .join()
                    .map_err(|_| internal("self-test thread panicked".into()))?;
            }
            if sum == 0 {
                return Err(internal("threads computed nothing".into()));
            }
            Ok(fake_result(job))
        }
        "connect" => Err(probe_err("connect", try_connect(arg))),
        "fork" => Err(probe_err("fork", try_fork())),
        "exec" => Err(probe_err("exec", try_exec())),
        "write" => Err(probe_err("write", try_write(Path::new(arg)))),
        "read" => Err(probe_err("read", try_read(Path::new(arg)))),
        "kill-parent" => Err(probe_err("kill-parent", try_kill_parent())),
        other => Err(WorkerError {
            kind: ErrorKind::BadJob,
            message: format!("unknown self-test mode `{other}`"),
        }),
    }
}

fn internal(message: String) -> WorkerError {
    WorkerError {
        kind: ErrorKind::Internal,
        message,
    }
}

/// Probe results travel as an error so the test can read them: "selftest <what>:
/// allowed" or "selftest <what>: denied: <os error>".
fn probe_err(what: &str, r: Result<(), std::io::Error>) -> WorkerError {
    internal(match r {
        Ok(()) => format!("selftest {what}: allowed"),
        Err(e) => format!("selftest {what}: denied: {e}"),
    })
}

fn alloc_forever() -> ! {
    let mut hoard: Vec<Vec<u8>> = Vec::new();
    loop {
        // Touch every page so the memory is really committed.
        hoard.push(vec![1u8; 64 << 20]);
        std::hint::black_box(&hoard);
    }
}

fn try_connect(port: &str) -> Result<(), std::io::Error> {
    let port: u16 = port
        .parse()
        .map_err(|_| std::io::Error::other("bad port"))?;
    let addr = SocketAddr::from(([127, 0, 0, 1], port));
    let mut s = TcpStream::connect_timeout(&addr, Duration::from_secs(3))?;
    s.write_all(b"escaped the sandbox\n")?;
    Ok(())
}

fn try_fork() -> Result<(), std::io::Error> {
    // SAFETY: the child immediately _exits.
    let pid = unsafe { libc::fork() };
    if pid == 0 {
        unsafe { libc::_exit(0) };
    }
    if pid < 0 {
        return Err(std::io::Error::last_os_error());
    }
    // SAFETY: reaping our own child.
    unsafe { libc::waitpid(pid, std::ptr::null_mut(), 0) };
    Ok(())
}

fn try_exec() -> Result<(), std::io::Error> {
    std::process::Command::new("/bin/true").status().map(|_| ())
}

fn try_write(path: &Path) -> Result<(), std::io::Error> {
    let mut f = std::fs::File::create(path)?;
    f.write_all(b"written from the sandbox\n")
}

fn try_read(path: &Path) -> Result<(), std::io::Error> {
    std::fs::read(path).map(|_| ())
}

fn try_kill_parent() -> Result<(), std::io::Error> {
    // Signal 0 only checks permission; nothing is delivered even if allowed.
    // SAFETY: kill with signal 0 has no effect besides the permission check.
    let rc = unsafe { libc::kill(libc::getppid(), 0) };
    if rc != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}

/// What `--check-sandbox` verifies after confining itself: each entry is active
/// when the sandbox behaved as it must.
pub fn probes(assets_dir: &Path) -> Vec<SandboxMechanism> {
    let mut out = Vec::new();
    let mut expect_denied = |name: &str, r: Result<(), std::io::Error>| {
        out.push(SandboxMechanism {
            name: format!("probe:{name}"),
            active: r.is_err(),
            detail: match r {
                Ok(()) => "ALLOWED — the sandbox does not stop this".into(),
                Err(e) => format!("denied as it must be ({e})"),
            },
        });
    };
    // A listener in our own (empty) namespace would not prove anything; port 9
    // (discard) on the host's loopback is the target.
    expect_denied("tcp-connect-127.0.0.1", try_connect("9"));
    expect_denied("fork", try_fork());
    expect_denied("exec", try_exec());
    expect_denied(
        "write-tmp",
        try_write(&std::env::temp_dir().join("d3il-sandbox-probe")),
    );
    expect_denied("read-etc-passwd", try_read(Path::new("/etc/passwd")));
    expect_denied("signal-parent", try_kill_parent());
    let assets_ok = std::fs::read_dir(assets_dir).map(|_| ());
    out.push(SandboxMechanism {
        name: "probe:read-assets".into(),
        active: assets_ok.is_ok(),
        detail: match assets_ok {
            Ok(()) => format!("{} is readable", assets_dir.display()),
            Err(e) => format!("{} is NOT readable ({e})", assets_dir.display()),
        },
    });
    let threads = std::thread::spawn(|| 42).join().map(|_| ());
    out.push(SandboxMechanism {
        name: "probe:threads".into(),
        active: threads.is_ok(),
        detail: if threads.is_ok() {
            "threads can be started (rayon, tract)".into()
        } else {
            "threads can NOT be started".into()
        },
    });
    out
}

/// A result that is obviously a self-test (evaluator version `selftest`), so it
/// can never be mistaken for a measurement.
fn fake_result(job: &Job) -> EvalResult {
    let zero = Estimate::without_interval(0.0, d3il_protocol::NoInterval::NoData);
    EvalResult {
        manifest: ProtocolManifest {
            task: job.task,
            task_version: "selftest".into(),
            obs_type: job.manifest.obs_type,
            protocol: job.protocol,
            robot_look: None,
            mjcf_sha256: String::new(),
            initial_states_sha256: String::new(),
            initial_states: String::new(),
            mujoco_version: String::new(),
            evaluator_version: "selftest".into(),
            n_contexts: 0,
            rollouts_per_context: 0,
            max_steps: 0,
            policy_sha256: String::new(),
            history: job.manifest.history,
            horizon: job.manifest.horizon,
            execute: job.manifest.execute,
            seed: job.seed,
            simulated_once: false,
            build: None,
            perturbation: None,
        },
        metrics: Metrics {
            success_rate: zero,
            behaviour_entropy: zero,
            conditional_entropy: zero,
            stacking: None,
            stacking_levels: None,
            inference_ms: 0.0,
        },
        per_context: vec![],
        rollouts: vec![],
        rollouts_ended_unstable: 0,
    }
}
