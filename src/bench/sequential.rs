//! `d3il bench sequential`: how many rollouts the sequential paired test
//! (d3il_metrics::sequential) saves against the fixed-size paired test of
//! equal power, and that it keeps its type-I error, by Monte Carlo over a
//! grid of success-rate pairs. The protocol view (the last line)
//! runs the test as a comparison does, deciding by the boundary calibrated
//! to the protocol's horizon (d3il_metrics::horizon); the anytime e-value
//! rule is measured beside it, and alone in the design view (which needs
//! runs longer than the horizon). docs/sequential.md has the method and the
//! figures.

use d3il_metrics::sequential::{Decision, FixedPairedTest};
use d3il_metrics::sequential_sim::{
    discordant_probabilities, independent_discordance, simulate, truncate, DecisionTable, Simulated,
};
use rayon::prelude::*;

/// Level of both tests (two-sided).
const ALPHA: f64 = 0.05;
/// Most pairs a sequential run may use: the paper protocol's 480 rollouts
/// per policy on Aligning (60 initial states × 8).
const MAX_PAIRS: usize = 480;
/// The power the fixed-size test is asked for is the sequential test's,
/// capped here: a measured power of 1 would ask for an infinite fixed test.
/// The cap favours the fixed test.
const POWER_CAP: f64 = 0.99;
/// Equal rates (the type-I error) get this many times the runs under the
/// calibrated boundary.
const NULL_RUNS_FACTOR: usize = 25;
/// The power both tests are designed for in the "design view".
const DESIGN_POWER: f64 = 0.9;
/// Most pairs a simulated run goes on for (the design view's truncation
/// is looked for up to here); `--smoke` stops at 600.
const CAP_PAIRS: usize = 2000;

struct Measured {
    a_name: &'static str,
    b_name: &'static str,
    pairs: usize,
    a_successes: usize,
    b_successes: usize,
    discordant: usize,
}

/// `d3il eval --task aligning --protocol paper --json` (60 initial states
/// × 8 rollouts, seed 0) of the two scripted experts `scripted:aligning:inside`
/// (A) and `scripted:aligning:outside` (B), paired by (initial state,
/// rollout). (The ONNX fixtures under assets/fixtures/agents are untrained:
/// bc_mlp succeeds on none of the 480, which would say nothing about
/// discordance.) Both are deterministic, so a state's 8 rollouts agree: 27
/// of the 60 states are discordant.
const MEASURED: Measured = Measured {
    a_name: "scripted:aligning:inside",
    b_name: "scripted:aligning:outside",
    pairs: 480,
    a_successes: 336,
    b_successes: 280,
    discordant: 216,
};

/// Discordant pairs measured on our own paired evaluations ([`MEASURED`]),
/// as a share of what independent outcomes at the same rates would give. A
/// grid pair (a, b) is simulated "paired" with
/// `ratio · (a(1 − b) + b(1 − a))` discordant pairs (at least |a − b|),
/// "unpaired" with ratio 1.
pub fn measured_discordance_ratio() -> f64 {
    let n = MEASURED.pairs as f64;
    let (a, b) = (
        MEASURED.a_successes as f64 / n,
        MEASURED.b_successes as f64 / n,
    );
    MEASURED.discordant as f64 / n / independent_discordance(a, b)
}

struct Row {
    a: f64,
    b: f64,
    discordance: f64,
    /// Decided by the boundary calibrated to `MAX_PAIRS`.
    protocol: Simulated,
    /// The e-value rule truncated at `MAX_PAIRS`, and the fixed test's pairs
    /// for its power.
    e_protocol: Simulated,
    e_protocol_fixed: Option<usize>,
    /// Pairs the fixed test needs for the sequential test's power at
    /// `MAX_PAIRS` (capped at `POWER_CAP`).
    protocol_fixed: Option<usize>,
    /// Designed for `DESIGN_POWER`: the sequential test truncated at the
    /// fewest pairs that give it that power, and the fixed test's pairs for
    /// it (`None` when not reached within `CAP_PAIRS`).
    design: Option<(u32, Simulated, usize)>,
}

fn simulate_pair(
    a: f64,
    b: f64,
    ratio: f64,
    runs: usize,
    seed: u64,
    (table, horizon): (&DecisionTable, &DecisionTable),
) -> Row {
    let cap = table.max_pairs();
    let discordance = (ratio * independent_discordance(a, b)).max((a - b).abs());
    let (p10, p01) = discordant_probabilities(a, b, discordance);
    // Equal rates only need the protocol's size.
    let all = simulate(
        table,
        p10,
        p01,
        runs,
        if a == b { MAX_PAIRS } else { cap },
        seed,
    );
    let e_protocol = truncate(&all, MAX_PAIRS as u32);
    // The same seed: the same first pairs, decided by the calibrated
    // boundary. Its type-I error is close to α by design, so equal rates
    // get `NULL_RUNS_FACTOR` times the runs (a standard error of 0.0007).
    let n = if a == b {
        NULL_RUNS_FACTOR * runs
    } else {
        runs
    };
    let protocol = truncate(
        &simulate(horizon, p10, p01, n, MAX_PAIRS, seed),
        MAX_PAIRS as u32,
    );
    let mut fixed = FixedPairedTest::new(ALPHA);
    let (protocol_fixed, e_protocol_fixed, design) = if a > b {
        let pf = fixed.pairs_for_power(p10, p01, protocol.a_better.min(POWER_CAP), 100_000);
        let ef = fixed.pairs_for_power(p10, p01, e_protocol.a_better.min(POWER_CAP), 100_000);
        // Fewest pairs at which the truncated sequential test has the power.
        let mut decided: Vec<u32> = all
            .iter()
            .filter(|r| r.decision == Some(Decision::ABetter))
            .map(|r| r.pair)
            .collect();
        decided.sort_unstable();
        let need = (DESIGN_POWER * runs as f64).ceil() as usize;
        let design = decided.get(need.saturating_sub(1)).and_then(|&n| {
            let f = fixed.pairs_for_power(p10, p01, DESIGN_POWER, 100_000)?;
            Some((n, truncate(&all, n), f))
        });
        (pf, ef, design)
    } else {
        (None, None, None)
    };
    Row {
        a,
        b,
        discordance: p10 + p01,
        protocol,
        e_protocol,
        e_protocol_fixed,
        protocol_fixed,
        design,
    }
}

pub fn run(smoke: bool) -> anyhow::Result<()> {
    // STEP's grid (Snyder et al. 2025): rates 0.05, 0.15, ..., 0.95, all 45
    // unequal pairs; the 10 equal pairs measure the type-I error.
    let rates: Vec<f64> = if smoke {
        vec![0.15, 0.55, 0.85]
    } else {
        (0..10).map(|i| 0.05 + 0.1 * i as f64).collect()
    };
    let runs = if smoke { 200 } else { 4000 };
    let ratio = measured_discordance_ratio();
    let table = DecisionTable::new(ALPHA, if smoke { 600 } else { CAP_PAIRS });
    let horizon = DecisionTable::with_horizon(ALPHA, MAX_PAIRS);
    let boundary = d3il_metrics::sequential::CalibratedBoundary::new(ALPHA, MAX_PAIRS);
    println!(
        "sequential paired test (two-sided, alpha {ALPHA}): boundary calibrated to {MAX_PAIRS} pairs \
         (|w - l| >= ceil({:.4} sqrt(w + l)), last look at pair {MAX_PAIRS}; exact type-I {:.5}), and the mixture e-process \
         (e-value >= 1/alpha, anytime) beside it",
        boundary.z(),
        boundary.type_i_error()
    );
    println!(
        "both against the exact fixed-size sign test \
         of equal power; {runs} runs per rate pair ({} per equal pair under the boundary); paired: {ratio:.3} x the discordant pairs of independent outcomes \
         (measured: {} of {} pairs discordant, {} {} and {} {} successes, Aligning paper protocol)",
        NULL_RUNS_FACTOR * runs, MEASURED.discordant, MEASURED.pairs, MEASURED.a_name, MEASURED.a_successes, MEASURED.b_name, MEASURED.b_successes
    );
    println!(
        "protocol view: runs stop at {MAX_PAIRS} pairs (Aligning's 60 x 8), fixed test of the sequential test's power (at most {POWER_CAP}); \
         design view: both tests at power {DESIGN_POWER}, the sequential one truncated at the fewest pairs that give it that power"
    );
    let cap = table.max_pairs();
    let mut summary = vec![];
    for (label, r) in [("paired", ratio), ("unpaired", 1.0)] {
        let mut cells = vec![];
        for (i, &a) in rates.iter().enumerate() {
            for (j, &b) in rates.iter().enumerate().take(i + 1) {
                cells.push((
                    a,
                    b,
                    (i * 100 + j) as u64 + if r == 1.0 { 50_000 } else { 0 },
                ));
            }
        }
        let mut rows: Vec<Row> = cells
            .par_iter()
            .map(|&(a, b, s)| simulate_pair(a, b, r, runs, s, (&table, &horizon)))
            .collect();
        rows.sort_by(|x, y| (x.a, x.b).partial_cmp(&(y.a, y.b)).unwrap());
        let (equal, unequal): (Vec<&Row>, Vec<&Row>) = rows.iter().partition(|r| r.a == r.b);
        println!(
            "\n{label}: equal rates (type-I error: share of runs deciding either way by {MAX_PAIRS} pairs; boundary, e-value)"
        );
        let (mut worst, mut e_worst): (f64, f64) = (0.0, 0.0);
        for t in &equal {
            let e = t.protocol.a_better + t.protocol.b_better;
            let ee = t.e_protocol.a_better + t.e_protocol.b_better;
            worst = worst.max(e);
            e_worst = e_worst.max(ee);
            println!(
                "{label}:   {:.2} = {:.2}  discordant {:.3}  type-I {:.4} (exact {:.4})  e-value: {:.4}",
                t.a,
                t.b,
                t.discordance,
                e,
                boundary.type_i_at(t.discordance),
                ee
            );
        }
        println!(
            "{label}: largest type-I error {worst:.4} (boundary), {e_worst:.4} (e-value) (must be <= {ALPHA})"
        );
        println!(
            "{label}: {:>5} {:>5} {:>6} | {:>6} {:>7} {:>8} {:>6} {:>6} | e-value: {:>6} {:>8} {:>6} {:>6} | {:>6} {:>8} {:>6} {:>6}",
            "A",
            "B",
            "disc.",
            "power",
            "wrong",
            "E[pairs]",
            "fixed",
            "ratio",
            "power",
            "E[pairs]",
            "fixed",
            "ratio",
            "trunc.",
            "E[pairs]",
            "fixed",
            "ratio"
        );
        let (mut p_seq, mut p_fixed, mut d_seq, mut d_fixed) = (0.0, 0.0, 0.0, 0.0);
        let (mut e_seq, mut e_fixed) = (0.0, 0.0);
        let mut missing = 0;
        let opt = |n: Option<usize>, used: f64| match n {
            Some(f) => (format!("{f}"), format!("{:.2}", used / f as f64)),
            None => ("-".into(), "-".into()),
        };
        for row in &unequal {
            let design = row.design.map_or(
                format!("{:>6} {:>8} {:>6} {:>6}", "-", "-", "-", "-"),
                |(n, s, f)| {
                    format!(
                        "{n:>6} {:>8.1} {f:>6} {:>6.2}",
                        s.mean_pairs,
                        s.mean_pairs / f as f64
                    )
                },
            );
            let (pf, pr) = opt(row.protocol_fixed, row.protocol.mean_pairs);
            let (ef, er) = opt(row.e_protocol_fixed, row.e_protocol.mean_pairs);
            println!(
                "{label}: {:>5.2} {:>5.2} {:>6.3} | {:>6.3} {:>7.4} {:>8.1} {pf:>6} {pr:>6} | e-value: {:>6.3} {:>8.1} {ef:>6} {er:>6} | {design}",
                row.a,
                row.b,
                row.discordance,
                row.protocol.a_better,
                row.protocol.b_better,
                row.protocol.mean_pairs,
                row.e_protocol.a_better,
                row.e_protocol.mean_pairs,
            );
            if let Some(f) = row.protocol_fixed {
                p_seq += row.protocol.mean_pairs;
                p_fixed += f as f64;
            }
            if let Some(f) = row.e_protocol_fixed {
                e_seq += row.e_protocol.mean_pairs;
                e_fixed += f as f64;
            }
            match row.design {
                Some((_, s, f)) => {
                    d_seq += s.mean_pairs;
                    d_fixed += f as f64;
                }
                None => missing += 1,
            }
        }
        let mean_power =
            unequal.iter().map(|r| r.protocol.a_better).sum::<f64>() / unequal.len() as f64;
        println!(
            "{label}: {} rate pairs, mean power at {MAX_PAIRS} pairs {mean_power:.3}; summed expected pairs: protocol view {p_seq:.0} \
             sequential vs {p_fixed:.0} fixed (ratio {:.3}); e-value rule {e_seq:.0} vs {e_fixed:.0} (ratio {:.3}); e-value rule, \
             design view {d_seq:.0} vs {d_fixed:.0} (ratio {:.3}, {missing} pairs without power {DESIGN_POWER} within {cap} pairs left out)",
            unequal.len(),
            p_seq / p_fixed,
            e_seq / e_fixed,
            d_seq / d_fixed
        );
        summary.push((
            label,
            worst,
            p_seq / p_fixed,
            e_seq / e_fixed,
            d_seq / d_fixed,
        ));
    }
    println!();
    for (label, worst, protocol, e_protocol, design) in &summary {
        println!(
            "{label}: largest type-I error {worst:.4} (alpha {ALPHA}); ratio protocol view {protocol:.3} \
             (e-value rule {e_protocol:.3}, its design view {design:.3})"
        );
    }
    println!(
        "ratio sequential/fixed expected rollouts at equal power (paired, protocol view, summed over the grid): {:.3} (goal <= 0.6)",
        summary[0].2
    );
    Ok(())
}
