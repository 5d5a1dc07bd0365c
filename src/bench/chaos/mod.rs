//! `d3il bench chaos`: the whole service under faults. A throw-away
//! PostgreSQL, two front ends (`d3il serve --workers 0 --shards 3`, one with
//! the submission-time dry run and one without) and three worker hosts
//! (`d3il workers`) on 127.0.0.1 take a stream of quick-protocol
//! submissions (good ONNX fixtures, a remote endpoint, hostile fixtures,
//! duplicates, uploads cut off mid-body) while a fault injector kills a
//! random front end, worker host, `d3il worker` process or the database
//! with SIGKILL every few seconds and starts it again (the database on the
//! same data directory and port).
//!
//! At the end every accepted submission must be completed or failed with a
//! reason its submitter can act on, none lost, every completed result equal
//! bit for bit (but for the measured inference time) to a plain `d3il eval`
//! of the same policy, protocol and seed, and no row or file left behind.
//! The same stream without faults (a shorter one) gives the quiet p99 the
//! last line compares with:
//! `submissions N, faults F, lost L, mismatched M, p99 submission-to-result X s against a quiet run Y s, ratio X/Y`.
//! Any broken promise makes the command fail after printing its table.

mod audit;
mod cluster;
mod load;
mod soak;

use anyhow::Context;
use std::path::Path;
use std::time::Duration;

/// How long and how hard one run pushes.
#[derive(Debug, Clone)]
pub struct Plan {
    /// Submission requests of the soak (every kind counts).
    pub submissions: usize,
    /// Faults the soak injects at least (it goes on until both are reached).
    pub faults: usize,
    /// Submission requests of the quiet run.
    pub quiet_submissions: usize,
    /// Mean time between two submission requests.
    pub submit_every: Duration,
    /// Mean time between two faults.
    pub fault_every: Duration,
    /// How long the accepted submissions may take to end after the stream.
    pub settle: Duration,
    /// Whether the hostile fixture that runs into the CPU limit is sent.
    pub endless: bool,
}

impl Plan {
    pub fn new(smoke: bool) -> Plan {
        if smoke {
            Plan {
                submissions: 10,
                faults: 4,
                quiet_submissions: 4,
                submit_every: Duration::from_millis(1500),
                fault_every: Duration::from_secs(3),
                settle: Duration::from_secs(240),
                endless: false,
            }
        } else {
            Plan {
                submissions: 160,
                faults: 50,
                quiet_submissions: 30,
                submit_every: Duration::from_millis(2500),
                fault_every: Duration::from_secs(5),
                settle: Duration::from_secs(900),
                endless: true,
            }
        }
    }
}

/// The `d3il` every process of the run is started from: a copy of this
/// executable made at the start, so that a rebuild meanwhile (the binary
/// replaced under `target/`) changes nothing in the middle of a run.
static EXE: std::sync::OnceLock<std::path::PathBuf> = std::sync::OnceLock::new();

fn exe() -> anyhow::Result<std::path::PathBuf> {
    EXE.get()
        .cloned()
        .context("the chaos bench's copy of d3il is made at its start")
}

pub fn run(smoke: bool) -> anyhow::Result<()> {
    let plan = Plan::new(smoke);
    let dir = std::env::temp_dir().join(format!("d3il-bench-chaos-{}", std::process::id()));
    std::fs::create_dir_all(&dir).with_context(|| format!("creating {}", dir.display()))?;
    let copy = dir.join("d3il");
    std::fs::copy(std::env::current_exe()?, &copy)
        .with_context(|| format!("copying the d3il executable to {}", copy.display()))?;
    let _ = EXE.set(copy);
    let result = bench(&dir, &plan);
    if result.is_ok() {
        let _ = std::fs::remove_dir_all(&dir);
    } else {
        eprintln!("logs of the run are kept in {}", dir.display());
    }
    result
}

fn bench(dir: &Path, plan: &Plan) -> anyhow::Result<()> {
    let started = std::time::Instant::now();
    let endpoint = load::Endpoint::start()?;
    // Worker hosts take no job before the build's drift canary has run; it
    // runs once per build and is cached, so that the first host start of
    // the quiet run would otherwise hold its first jobs for it.
    let canary = std::process::Command::new(exe()?)
        .args(["verify", "--json", "--cached"])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .status()
        .context("running d3il verify")?;
    if !canary.success() {
        eprintln!("note: d3il verify reports drift for this build; the hosts' results say so");
    }
    eprintln!(
        "chaos soak: PostgreSQL, 2 front ends, 3 worker hosts; quick protocol; {} submissions and at least {} faults (quiet run: {} submissions)",
        plan.submissions, plan.faults, plan.quiet_submissions
    );
    let quiet = soak::phase(&dir.join("quiet"), plan, false, &endpoint)?;
    let chaos = soak::phase(&dir.join("chaos"), plan, true, &endpoint)?;
    let verdicts = audit::compare_with_plain_evals(dir, &[&quiet, &chaos], &endpoint)?;
    let (quiet_v, chaos_v) = (&verdicts[0], &verdicts[1]);
    print!(
        "{}",
        audit::table(&[("quiet", &quiet, quiet_v), ("chaos", &chaos, chaos_v)])
    );
    println!("{}", cluster::fault_summary(&chaos.faults));
    for problem in quiet_v.problems.iter().chain(&chaos_v.problems) {
        println!("problem: {problem}");
    }
    let accepted = chaos
        .sent
        .iter()
        .filter(|s| matches!(s.answer, load::Answer::Accepted(_)))
        .count();
    println!(
        "wall time {:.0} s; the soak's front ends accepted {accepted} of its {} submissions",
        started.elapsed().as_secs_f64(),
        chaos.sent.len()
    );
    let (x, y) = (chaos_v.p99, quiet_v.p99);
    println!(
        "submissions {}, faults {}, lost {}, mismatched {}, p99 submission-to-result {x:.1} s against a quiet run {y:.1} s, ratio {:.2}",
        chaos.sent.len(),
        chaos.faults.len(),
        quiet_v.lost + chaos_v.lost,
        quiet_v.mismatched + chaos_v.mismatched,
        if y > 0.0 { x / y } else { f64::NAN }
    );
    let broken = quiet_v.broken() + chaos_v.broken();
    anyhow::ensure!(
        broken == 0,
        "{broken} broken promise(s): see the `problem:` lines above"
    );
    Ok(())
}
