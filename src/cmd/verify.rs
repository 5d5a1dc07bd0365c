//! `d3il verify`: the drift canary (evaluator::canary). Re-runs the fixed
//! canary set, prints a table of what still matches the committed outcomes
//! (`assets/canary/expected.json`) and this build's physics fingerprint, and
//! fails when anything drifted. `--update` commits this build's outcomes as
//! the expectation (after a change that is meant to move numbers: a minor
//! version bump, noted in CHANGELOG.md).
//!
//! The fingerprint is cached per binary (its sha256) under
//! `$D3IL_CACHE_DIR` (default `$XDG_CACHE_HOME/d3il` or `~/.cache/d3il`), so
//! that `d3il eval` and `d3il serve` compute it once per build.

use anyhow::{bail, Context};
use d3il_evaluator::canary::{self, EntryCheck, Outcomes};
use serde::{Deserialize, Serialize};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Print the checks and the fingerprint as JSON.
    #[arg(long)]
    pub json: bool,
    /// Write this build's outcomes to assets/canary/expected.json.
    #[arg(long)]
    pub update: bool,
    /// Print this binary's last report when there is one (kept per binary
    /// next to its fingerprint) instead of running the canary again.
    #[arg(long, conflicts_with = "update")]
    pub cached: bool,
}

/// What `d3il verify --json` prints (and the server shows).
#[derive(Debug, Serialize, Deserialize)]
pub struct VerifyReport {
    pub fingerprint: String,
    pub expected_fingerprint: Option<String>,
    pub passed: bool,
    pub entries: Vec<serde_json::Value>,
    pub seconds: f64,
}

fn cached_report() -> Option<VerifyReport> {
    cache_path("verify", "json")
        .and_then(|f| std::fs::read(f).ok())
        .and_then(|b| serde_json::from_slice::<VerifyReport>(&b).ok())
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // Held until this run has stored its report: a concurrent `--cached`
    // run (or `d3il eval`'s fingerprint) waits for it instead of running
    // the canary again.
    let mut _lock = None;
    if args.cached {
        if let Some(report) = cached_report() {
            return finish(&report, args.json, "");
        }
        _lock = canary_lock();
        if let Some(report) = cached_report() {
            return finish(&report, args.json, "");
        }
    }
    let assets = super::assets_dir();
    let t0 = std::time::Instant::now();
    if !args.json {
        println!(
            "drift canary: {} entries (quick protocol initial states, capped steps)",
            canary::ENTRIES.len()
        );
    }
    let json = args.json;
    let got = canary::run(&assets, &mut |o| {
        if !json {
            eprintln!("  ran {}", o.entry);
        }
    })?;
    let fingerprint = got.fingerprint();
    store_cached(&fingerprint);
    if args.update {
        let f = assets.join("canary/expected.json");
        std::fs::create_dir_all(f.parent().expect("has a parent"))?;
        std::fs::write(&f, serde_json::to_string_pretty(&got)? + "\n")
            .with_context(|| format!("writing {}", f.display()))?;
        println!("wrote {} (fingerprint {fingerprint})", f.display());
        return Ok(());
    }
    let expected = canary::expected(&assets).map_err(anyhow::Error::msg)?;
    let checks = canary::compare(&expected, &got);
    let passed = checks.iter().all(|c| c.first_difference.is_none())
        && checks.len() == expected.entries.len();
    let report = VerifyReport {
        expected_fingerprint: Some(expected.fingerprint()),
        fingerprint: fingerprint.clone(),
        passed,
        entries: checks
            .iter()
            .map(serde_json::to_value)
            .collect::<Result<_, _>>()?,
        seconds: t0.elapsed().as_secs_f64(),
    };
    if let Some(f) = cache_path("verify", "json") {
        store_atomically(&f, &serde_json::to_vec(&report)?);
    }
    finish(&report, args.json, &table(&checks))
}

/// Prints the report and fails on drift.
fn finish(report: &VerifyReport, json: bool, table: &str) -> anyhow::Result<()> {
    if json {
        println!("{}", serde_json::to_string_pretty(report)?);
    } else {
        print!("{table}");
        println!(
            "physics fingerprint of this build: {} (committed outcomes: {}), {:.1} s",
            report.fingerprint,
            report.expected_fingerprint.as_deref().unwrap_or("none"),
            report.seconds
        );
    }
    if !report.passed {
        let drifted: Vec<String> = report
            .entries
            .iter()
            .filter_map(|c| {
                Some(format!(
                    "{}: {}",
                    c["entry"].as_str()?,
                    c["first_difference"].as_str()?
                ))
            })
            .collect();
        bail!(
            "the simulator drifted from the committed canary outcomes: {}",
            drifted.join("; ")
        );
    }
    Ok(())
}

fn table(checks: &[EntryCheck]) -> String {
    let w = checks
        .iter()
        .map(|c| c.entry.len())
        .max()
        .unwrap_or(5)
        .max(5);
    let mut s = format!("{:<w$}  matching  status\n", "entry");
    for c in checks {
        s.push_str(&format!(
            "{:<w$}  {:>3} / {:<3} {}\n",
            c.entry,
            c.matching,
            c.rollouts,
            match &c.first_difference {
                None => "ok".to_string(),
                Some(d) => format!("DRIFTED: {d}"),
            }
        ));
    }
    s
}

fn cache_dir() -> PathBuf {
    if let Some(d) = std::env::var_os("D3IL_CACHE_DIR") {
        return PathBuf::from(d);
    }
    let base = std::env::var_os("XDG_CACHE_HOME")
        .map(PathBuf::from)
        .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
        .unwrap_or_else(std::env::temp_dir);
    let dir = base.join("d3il");
    // A home without a writable cache (some CI users) falls back to the
    // temporary directory, so the canary still runs once per binary.
    if std::fs::create_dir_all(&dir).is_ok() {
        dir
    } else {
        std::env::temp_dir().join("d3il-cache")
    }
}

/// A cache file of this binary (keyed by the binary's sha256): `<what>-<sha>.<ext>`.
/// None under the drift test's deliberate controller change, whose
/// outcomes are not this build's.
fn cache_path(what: &str, ext: &str) -> Option<PathBuf> {
    if std::env::var_os("D3IL_DRIFT_TEST_KP_SCALE").is_some() {
        return None;
    }
    static SHA: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    let sha =
        SHA.get_or_init(|| d3il_server::fidelity::file_sha256(&std::env::current_exe().ok()?).ok());
    let sha = sha.as_deref()?;
    Some(cache_dir().join(format!("{what}-{}.{ext}", &sha[..16])))
}

fn cache_file() -> Option<PathBuf> {
    cache_path("fingerprint", "txt")
}

fn store_atomically(f: &std::path::Path, bytes: &[u8]) {
    let _ = std::fs::create_dir_all(f.parent().expect("has a parent"));
    let tmp = f.with_extension(format!("tmp{}", std::process::id()));
    if std::fs::write(&tmp, bytes).is_ok() {
        let _ = std::fs::rename(&tmp, f);
    }
}

fn store_cached(fingerprint: &str) {
    if let Some(f) = cache_file() {
        store_atomically(&f, fingerprint.as_bytes());
    }
}

fn cached_fingerprint() -> Option<String> {
    let s = std::fs::read_to_string(cache_file()?).ok()?;
    let s = s.trim();
    (s.len() == 16 && s.bytes().all(|b| b.is_ascii_hexdigit())).then(|| s.to_string())
}

/// An exclusive lock on this binary's canary (a lock file next to its
/// cache), held while one process runs the canary: the test suite and a
/// cluster start many `d3il` processes of a fresh build at once, and
/// without it each would compute the same fingerprint (half a minute of
/// CPU each). None when there is no cache, or the lock cannot be taken:
/// then the canary just runs.
fn canary_lock() -> Option<std::fs::File> {
    let f = std::fs::File::create(cache_path("canary", "lock")?).ok()?;
    f.lock().ok()?;
    Some(f)
}

/// This build's physics fingerprint: from the cache, or by running the
/// canary once (about half a minute; said on stderr).
pub fn build_fingerprint() -> anyhow::Result<String> {
    if let Some(fp) = cached_fingerprint() {
        return Ok(fp);
    }
    let _lock = canary_lock();
    if let Some(fp) = cached_fingerprint() {
        return Ok(fp);
    }
    eprintln!("computing this build's physics fingerprint (the drift canary, once per build)...");
    let got: Outcomes = canary::run(&super::assets_dir(), &mut |_| {})?;
    let fp = got.fingerprint();
    store_cached(&fp);
    Ok(fp)
}

/// The git commit this binary was built from (build.rs).
pub const GIT_COMMIT: &str = env!("D3IL_GIT_COMMIT");

/// This build's identity for a result's manifest.
pub fn this_build() -> anyhow::Result<d3il_protocol::BuildIdentity> {
    Ok(d3il_protocol::BuildIdentity {
        git_commit: GIT_COMMIT.to_string(),
        physics_fingerprint: Some(build_fingerprint()?),
    })
}
