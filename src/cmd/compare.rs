//! `d3il compare a.json b.json`: paired comparison of two evaluation results
//! (the `--json` outputs of `d3il eval`) on the same initial states.

use anyhow::Context;
use d3il_metrics::Bootstrap;
use d3il_protocol::{Comparison, EvalResult, PairedDifference};
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    /// Result A (`d3il eval --json a.json`); with `--task`, policy A, as
    /// `d3il eval --policy` takes it (ONNX file, `scripted:NAME`, `ws://…`).
    pub a: PathBuf,
    /// Result B, on the same task, protocol and initial states; with
    /// `--task`, policy B.
    pub b: PathBuf,
    /// Bootstrap resamples and randomisation-test permutations.
    #[arg(long, default_value_t = 2000)]
    pub resamples: usize,
    /// Seed of the resampling (ChaCha8); with `--sequential`, of the random
    /// order (and, with `--task`, of both evaluations: their noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Print the comparison as JSON instead of a table.
    #[arg(long)]
    pub json: bool,
    /// Replay the paired outcomes (by initial state and rollout) in a random
    /// order seeded by `--seed` through the anytime-valid sequential test,
    /// and report when it would have stopped (docs/sequential.md).
    #[arg(long)]
    pub sequential: bool,
    /// Level of the sequential test (two-sided).
    #[arg(long, default_value_t = 0.05, requires = "sequential")]
    pub alpha: f64,
    /// With `--sequential`: also stop with "no difference larger than δ"
    /// when the confidence sequence of rate(A) − rate(B) lies inside (−δ, δ).
    #[arg(long, requires = "sequential")]
    pub delta: Option<f64>,
    /// With `--sequential`: race policies A and B on this task instead of
    /// replaying results: both run interleaved on the same initial states in
    /// the same random order, stopping at the test's decision.
    #[arg(long, requires = "sequential")]
    pub task: Option<d3il_protocol::TaskId>,
    /// With `--task`: `paper` or `quick`.
    #[arg(long, default_value = "paper", requires = "task")]
    pub protocol: d3il_protocol::ProtocolKind,
    /// With `--task`: rollouts simulated at once per policy (fewer stop
    /// sooner after a decision, more run faster).
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

/// Compares two result files (main.rs sends `--task T A B`, a race of two
/// policies, to `cmd::race`).
pub fn run(args: Args) -> anyhow::Result<()> {
    let a = load(&args.a)?;
    let b = load(&args.b)?;
    if args.sequential {
        return sequential(&a, &b, &args);
    }
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

/// A paired difference's interval as `+0.100 – +0.300` (signed), or the
/// short reason there is none.
pub fn paired_interval_text(e: &d3il_protocol::Estimate) -> String {
    match e.interval() {
        Some((lo, hi)) => format!("{lo:+.3} – {hi:+.3}"),
        None => e.interval_text(3),
    }
}

fn sequential(a: &EvalResult, b: &EvalResult, args: &Args) -> anyhow::Result<()> {
    d3il_protocol::race::check_race_params(args.alpha, args.delta)
        .map_err(|e| anyhow::anyhow!("--{}", e.message))?;
    let (pairs, per_state) = d3il_metrics::sequential::paired_outcomes_per_unit(a, b)?;
    let r = d3il_metrics::sequential::replay(&pairs, args.alpha, args.delta, args.seed);
    if args.json {
        let mut v = serde_json::to_value(&r)?;
        v["pair"] = (if per_state {
            "initial state"
        } else {
            "rollout"
        })
        .into();
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        if per_state {
            println!(
                "both policies did the same in every rollout of each initial state (deterministic): one pair per initial state"
            );
        }
        print!("{}", render_sequential(&r));
    }
    Ok(())
}

/// The replay as plain text; its last line says what was saved.
pub fn render_sequential(r: &d3il_metrics::sequential::Replay) -> String {
    let mut s = format!(
        "sequential paired comparison A vs B, replayed in random order (seed {}), alpha {}{}\n",
        r.seed,
        r.alpha,
        r.delta
            .map(|d| format!(", margin δ {d}"))
            .unwrap_or_default()
    );
    s += &format!(
        "success rate over all {} pairs: A {:.3}, B {:.3}\n",
        r.pairs_total, r.rate_a, r.rate_b
    );
    match (&r.decision, r.decided_at) {
        (Some(d), Some(at)) => s += &format!("decision: {d} at pair {at} of {}\n", r.pairs_total),
        _ => {
            s += &format!(
                "decision: none after all {} pairs (the fixed-size test used the same pairs)\n",
                r.pairs_total
            )
        }
    }
    s += &format!(
        "e-value {:.3}, anytime-valid p-value {:.4}; discordant pairs so far: A won {}, B won {}\n",
        r.e_value, r.p_value, r.discordant.0, r.discordant.1
    );
    s += &d3il_metrics::horizon::rule_line(r.alpha, r.pairs_total as usize);
    s.push('\n');
    s += &d3il_metrics::horizon::decided_by(r.alpha, r.pairs_total as usize, r.decision.as_deref());
    s += ".\n";
    if let Some((lo, hi)) = r.difference_interval {
        s += &format!("confidence sequence of A − B: {lo:+.3} – {hi:+.3}\n");
    }
    s += &format!(
        "fixed-size paired test (exact sign test on all {} pairs): p = {:.4}\n",
        r.pairs_total, r.fixed_p_value
    );
    s += &format!(
        "rollouts used: {} of {} ({} per policy), ratio {:.3} of the fixed-size test\n",
        2 * r.pairs_used,
        2 * r.pairs_total,
        r.pairs_used,
        r.pairs_used as f64 / r.pairs_total.max(1) as f64
    );
    s
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_sequential_report_says_when_and_what_it_decided_and_what_it_saved() {
        let mut pairs = vec![(true, false); 40];
        pairs.extend([(false, true); 5]);
        pairs.extend([(true, true); 155]);
        let r = d3il_metrics::sequential::replay(&pairs, 0.05, None, 3);
        let text = super::render_sequential(&r);
        let at = r.decided_at.unwrap();
        assert!(
            text.contains(&format!("decision: A better at pair {at} of 200")),
            "{text}"
        );
        assert!(
            text.contains(&format!("rollouts used: {} of 400", 2 * at)),
            "{text}"
        );
        assert!(text.contains("anytime-valid p-value"), "{text}");
        let none = d3il_metrics::sequential::replay(&[(true, true); 30], 0.05, Some(0.5), 0);
        let text = super::render_sequential(&none);
        assert!(text.contains("decision: "), "{text}");
        assert!(text.contains("confidence sequence of A − B"), "{text}");
    }
}
