//! `d3il compare a.json b.json`: paired comparison of two evaluation results
//! (the `--json` outputs of `d3il eval`) on the same initial states.

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
    /// Seed of the resampling (ChaCha8).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print the comparison as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
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
        "{:<22} {:>7} {:>7} {:>8} {:>21} {:>8} {:>9}\n",
        "metric", "A", "B", "A − B", "95% CI", "p", "min. det."
    );
    let row = |name: &str, d: &PairedDifference| {
        format!(
            "{name:<22} {:>7.3} {:>7.3} {:>+8.3} {:>+9.3} – {:<+9.3} {:>8.4} {:>9.3}\n",
            d.a,
            d.b,
            d.difference.value,
            d.difference.ci_low,
            d.difference.ci_high,
            d.p_value,
            d.min_detectable
        )
    };
    s += &row("success rate", &c.success_rate);
    s += &row("conditional entropy", &c.conditional_entropy);
    for caveat in &c.caveats {
        s += &format!("note: {caveat}\n");
    }
    s += &format!(
        "p: randomisation test paired by initial state ({} permutations); min. det.: the difference detected with 80 % power at the 5 % level at this size\n",
        c.resamples
    );
    s
}
