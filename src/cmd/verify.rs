//! `d3il verify`: the drift canary (evaluator::canary). Re-runs the fixed
//! canary set, prints a table of what still matches the committed outcomes
//! (`assets/canary/expected.json`) and this build's physics fingerprint, and
//! fails when anything drifted. `--update` commits this build's outcomes as
//! the expectation (after a change that is meant to move numbers: a minor
//! version bump, noted in CHANGELOG.md).
//!
//! The fingerprint is cached per binary (`crate::common::build`), so that
//! `d3il eval` and `d3il serve` compute it once per build.

use crate::common::build::{cache_path, canary_lock, store_atomically, store_cached};
use anyhow::{bail, Context};
use d3il_evaluator::canary::{self, EntryCheck};
use serde::{Deserialize, Serialize};

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
    let assets = crate::common::assets_dir();
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
            "{}",
            drift_message(&drifted, d3il_evaluator::sim::scene::meshes_available())
        );
    }
    Ok(())
}

/// The error of a failed check: what drifted, and where image entries
/// drifted in a build without the Panda meshes, that the build is the likely
/// cause (its frames draw the primitive robot, not the committed outcomes').
fn drift_message(drifted: &[String], meshes: bool) -> String {
    let mut message = format!(
        "the simulator drifted from the committed canary outcomes: {}",
        drifted.join("; ")
    );
    if !meshes && drifted.iter().any(|d| d.contains("/image/")) {
        message.push_str(
            ". This build has no Panda meshes (assets/meshes/ was missing when it was \
             compiled), so image observations show the primitive robot: build with \
             `./dev`, which converts them first (scripts/panda_meshes.py)",
        );
    }
    message
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

#[cfg(test)]
mod tests {
    use super::drift_message;

    #[test]
    fn image_drift_in_a_build_without_meshes_names_the_meshes() {
        let image = vec!["aligning/image/aligning_image: rollout 0: differs".to_string()];
        let state =
            vec!["pushing/state/scripted:pushing:all-modes: rollout 0: differs".to_string()];
        assert!(drift_message(&image, false).contains("no Panda meshes"));
        assert!(!drift_message(&image, true).contains("meshes"));
        assert!(!drift_message(&state, false).contains("meshes"));
        assert!(drift_message(&state, false).starts_with(
            "the simulator drifted from the committed canary outcomes: pushing/state/"
        ));
    }
}
