//! `d3il compare a.json b.json`: paired comparison of two evaluation results
//! (the `--json` outputs of `d3il eval`) on the same initial states.
//! (`d3il compare --sequential` is a deprecated alias of `d3il race`, the
//! sequential test: main.rs sends it there with a note.)

use crate::common::text::paired_interval_text;
use anyhow::Context;
use d3il_metrics::Bootstrap;
use d3il_protocol::{Comparison, EvalResult, PairedDifference};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    /// Result A (`d3il eval --json a.json`).
    pub a: PathBuf,
    /// Result B, on the same task, protocol and initial states.
    pub b: PathBuf,
    /// Bootstrap resamples and randomisation-test permutations.
    #[arg(long, default_value_t = 2000)]
    pub resamples: usize,
    /// Seed of the resampling (ChaCha8); with `--sequential`, of the race's
    /// random order.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print the comparison as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Deprecated: `d3il race` (the same arguments without `--sequential`).
    #[arg(long)]
    pub sequential: bool,
    /// With `--sequential` (deprecated): `d3il race --alpha`.
    #[arg(long, default_value_t = 0.05, requires = "sequential")]
    pub alpha: f64,
    /// With `--sequential` (deprecated): `d3il race --delta`.
    #[arg(long, requires = "sequential")]
    pub delta: Option<f64>,
    /// With `--sequential` (deprecated): `d3il race --task`.
    #[arg(long, requires = "sequential")]
    pub task: Option<d3il_protocol::TaskId>,
    /// With `--task` (deprecated): `d3il race --protocol`.
    #[arg(long, default_value = "paper", requires = "task")]
    pub protocol: d3il_protocol::ProtocolKind,
    /// With `--task` (deprecated): `d3il race --max-live`.
    #[arg(long, default_value_t = 8, requires = "task")]
    pub max_live: usize,
}

fn load(path: &Path) -> anyhow::Result<EvalResult> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| {
        format!(
            "{} is not an evaluation result; pass files written by `d3il eval --json FILE`",
            path.display()
        )
    })
}

/// Compares two result files (main.rs sends the deprecated `--sequential`
/// to `cmd::race`).
pub fn run(args: Args) -> anyhow::Result<()> {
    let a = load(&args.a)?;
    let b = load(&args.b)?;
    let cfg = Bootstrap {
        resamples: args.resamples,
        confidence: 0.95,
        seed: args.seed,
    };
    let c = d3il_metrics::compare(&a, &b, &cfg)?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&c)?);
    } else {
        print!("{}", render(&c));
    }
    Ok(())
}

/// The comparison as a plain-text table.
pub fn render(c: &Comparison) -> String {
    let mut s = format!(
        "paired comparison A − B: task {}, {} protocol, {} initial states × {} rollouts\ninitial states: {} (sha256 {})\n",
        c.task, c.protocol.as_str(), c.n_contexts, c.rollouts_per_context, c.initial_states, c.initial_states_sha256
    );
    s += &format!(
        "{:<22} {:>7} {:>7} {:>8}   {:<32} {:>8} {:>9}\n",
        "metric", "A", "B", "A − B", "95% CI", "p", "min. det."
    );
    let row = |name: &str, d: &PairedDifference| {
        format!(
            "{name:<22} {:>7.3} {:>7.3} {:>+8.3}   {:<32} {:>8.4} {:>9.3}\n",
            d.a,
            d.b,
            d.difference.value,
            paired_interval_text(&d.difference),
            d.p_value,
            d.min_detectable
        )
    };
    s += &row("success rate", &c.success_rate);
    s += &row("conditional entropy", &c.conditional_entropy);
    for caveat in &c.caveats {
        s += &format!("note: {caveat}\n");
    }
    for (name, d) in [
        ("success rate", &c.success_rate),
        ("conditional entropy", &c.conditional_entropy),
    ] {
        s += &format!("{name}: {}\n", d.interval_note());
    }
    s += "min. det.: the difference detected with 80 % power at the 5 % level at this size\n";
    s
}
