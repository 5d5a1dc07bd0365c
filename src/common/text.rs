//! Documents that more than one command prints, as plain text, written once
//! so that the same document reads the same from every command: a
//! robustness document (`d3il eval --suite`, `d3il merge`, `d3il submit`), a
//! race and its replay (`d3il race`, `d3il submit --race`), and a paired
//! difference's interval (`d3il compare` and the robustness tables).

use d3il_protocol::race::RaceReport;
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::Estimate;
use std::path::Path;

/// A paired difference's interval as `+0.100 – +0.300` (signed), or the
/// short reason there is none.
pub fn paired_interval_text(e: &d3il_protocol::Estimate) -> String {
    match e.interval() {
        Some((lo, hi)) => format!("{lo:+.3} – {hi:+.3}"),
        None => e.interval_text(3),
    }
}

fn interval(e: &Option<Estimate>) -> String {
    match e {
        Some(e) => match e.interval() {
            Some((lo, hi)) => format!("{:.3} [{lo:.3}, {hi:.3}]", e.value),
            None => format!("{:.3} ({})", e.value, e.interval_text(3)),
        },
        None => "— (no success at level 0)".into(),
    }
}

/// A robustness document (`d3il eval --suite robustness`) as its tables: one
/// per axis, a row per level (level 0 first).
pub fn robustness(doc: &RobustnessResult) -> String {
    let c = &doc.control;
    let m = &c.manifest;
    let mut s = format!(
        "robustness of {} ({} × {} rollouts, {} protocol, seed {}); suite {} (sha256 {})\n",
        m.task,
        m.n_contexts,
        m.rollouts_per_context,
        m.protocol.as_str(),
        m.seed,
        doc.suite,
        doc.suite_sha256
    );
    let head = format!(
        "{:<18} {:>7} {:>8}   {:<32} {:>8} {:>7} {:>7} {:>8}\n",
        "level", "success", "drop", "95% CI", "p", "H", "H|s0", "retained"
    );
    for a in &doc.axes {
        s += &format!("\n{}: score {}\n", a.axis, interval(&a.score));
        s += &head;
        s += &format!(
            "{:<18} {:>7.3} {:>8}   {:<32} {:>8} {:>7.3} {:>7.3} {:>8}\n",
            "0 (standard)",
            c.metrics.success_rate.value,
            "",
            "",
            "",
            c.metrics.behaviour_entropy.value,
            c.metrics.conditional_entropy.value,
            "1"
        );
        for l in doc.levels.iter().filter(|l| l.axis == a.axis) {
            let d = &l.paired.success_rate;
            s += &format!(
                "{:<18} {:>7.3} {:>+8.3}   {:<32} {:>8.4} {:>7.3} {:>7.3} {:>8}\n",
                format!("{} ({})", l.level, l.setting.label),
                l.result.metrics.success_rate.value,
                d.difference.value,
                paired_interval_text(&d.difference),
                d.p_value,
                l.result.metrics.behaviour_entropy.value,
                l.result.metrics.conditional_entropy.value,
                l.retained
                    .map(|r| format!("{r:.3}"))
                    .unwrap_or_else(|| "—".into())
            );
        }
    }
    s += &format!("\noverall robustness score: {}\n", interval(&doc.overall));
    if let Some(c) = doc.score_coverage() {
        s += &format!("score intervals: {} (`d3il bench intervals`)\n", c.label);
    }
    let mut notes: Vec<String> = doc
        .levels
        .iter()
        .map(|l| l.paired.success_rate.interval_note())
        .collect();
    notes.sort();
    notes.dedup();
    for n in notes {
        s += &format!("drop: {n}\n");
    }
    let mut caveats: Vec<&String> = doc.levels.iter().flat_map(|l| &l.paired.caveats).collect();
    caveats.sort();
    caveats.dedup();
    for c in caveats {
        s += &format!("drop: note: {c}\n");
    }
    s += &format!(
        "drop: level 0 − level, paired by initial state (`d3il compare`, {} resamples); H: behaviour entropy; H|s0: conditional behaviour entropy; retained: share of level 0's successes kept, paired by initial state (Σ min(p0, p) / Σ p0, at most 1); score: retained averaged over the axis's levels (overall: over the axes), {:.0} % paired bootstrap interval (bias-corrected; for the score's expected value at this size; {})\n",
        doc.resamples,
        doc.confidence * 100.0,
        d3il_protocol::interval::score_coverage_note()
    );
    s
}

/// What the sequential test saw and how it stops, as a race and its replay
/// both print it: the e-value and anytime-valid p-value with the discordant
/// pairs (`discordant_label` says when they were counted), then the rule the
/// test stops by at this size (`pairs`, the most it could use) and what
/// decided it.
fn sequential_test_lines(
    discordant_label: &str,
    e_value: f64,
    p_value: f64,
    discordant: (u64, u64),
    alpha: f64,
    pairs: usize,
    decision: Option<&str>,
) -> String {
    let mut s = format!(
        "e-value {e_value:.3}, anytime-valid p-value {p_value:.4}; {discordant_label}: A won {}, B won {}\n",
        discordant.0, discordant.1
    );
    s += &d3il_metrics::horizon::rule_line(alpha, pairs);
    s.push('\n');
    s += &d3il_metrics::horizon::decided_by(alpha, pairs, decision);
    s += ".\n";
    s
}

/// The intervals of the pairs a race (or replay) used: the confidence
/// sequence of A − B when there is one, and the fixed-size comparison as
/// the race page shows it
/// (`d3il_metrics::rate_difference::fixed_size_comparison`).
fn used_pairs_lines(
    difference_interval: Option<(f64, f64)>,
    pairs_used: u64,
    discordant: (u64, u64),
    alpha: f64,
) -> String {
    let mut s = String::new();
    if let Some((lo, hi)) = difference_interval {
        s += &format!("confidence sequence of A − B: {lo:+.3} – {hi:+.3}\n");
    }
    s +=
        &d3il_metrics::rate_difference::fixed_size_comparison(pairs_used, discordant, alpha).line();
    s += ".\n";
    s
}

/// A race of two policies (`d3il race --task`, or a server's race that
/// `d3il submit --race` waited for) as plain text; its last line says what was saved.
pub fn race(r: &RaceReport, a: &Path, b: &Path) -> String {
    let mut s = format!(
        "race on {} ({} protocol, seed {}), alpha {}{}\nA: {}\nB: {}\n",
        r.task,
        r.protocol.as_str(),
        r.seed,
        r.alpha,
        r.delta
            .map(|d| format!(", margin δ {d}"))
            .unwrap_or_default(),
        a.display(),
        b.display()
    );
    s += &format!("pairs: one per {}\n", r.pair);
    match (&r.decision, r.decided_at) {
        (Some(d), Some(at)) => {
            s += &format!(
                "decision: {d} at pair {at} (initial state {} of {})\n",
                r.states_used, r.states_full
            )
        }
        _ => {
            s += &format!(
                "decision: none after all {} initial states (the protocol's full size)\n",
                r.states_full
            )
        }
    }
    s += &sequential_test_lines(
        "discordant pairs",
        r.e_value,
        r.p_value,
        r.discordant,
        r.alpha,
        r.pairs_full as usize,
        r.decision.as_deref(),
    );
    s += &format!(
        "success rate on the states used: A {:.3}, B {:.3}\n",
        r.rate_a, r.rate_b
    );
    s += &used_pairs_lines(r.difference_interval, r.pairs_used, r.discordant, r.alpha);
    s += &format!(
        "fixed-size paired test: the protocol's {} rollouts ({} pairs){}\n",
        r.rollouts_full,
        r.pairs_full,
        match r.fixed_pairs_for_power_90 {
            Some(n) => format!(
                "; at the discordance observed, the exact sign test needs {n} pairs for 90 % power"
            ),
            None => String::new(),
        }
    );
    s += &format!(
        "rollouts used: {} of {} (ratio {:.3}); simulated {} in {:.1} s\n",
        r.rollouts_used,
        r.rollouts_full,
        r.rollouts_used as f64 / r.rollouts_full.max(1) as f64,
        r.rollouts_simulated,
        r.seconds
    );
    s
}

/// A race replayed from two finished results (`d3il race a.json b.json`)
/// as plain text; its last line says what was saved.
pub fn race_replay(r: &d3il_metrics::sequential::Replay) -> String {
    let mut s = format!(
        "race replayed: A vs B in random order (seed {}), alpha {}{}\n",
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
    s += &sequential_test_lines(
        "discordant pairs so far",
        r.e_value,
        r.p_value,
        r.discordant,
        r.alpha,
        r.pairs_total as usize,
        r.decision.as_deref(),
    );
    s += &used_pairs_lines(r.difference_interval, r.pairs_used, r.discordant, r.alpha);
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
    fn the_replay_says_when_and_what_it_decided_and_what_it_saved() {
        let mut pairs = vec![(true, false); 40];
        pairs.extend([(false, true); 5]);
        pairs.extend([(true, true); 155]);
        let r = d3il_metrics::sequential::replay(&pairs, 0.05, None, 3);
        let text = super::race_replay(&r);
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
        let text = super::race_replay(&none);
        assert!(text.contains("decision: "), "{text}");
        assert!(text.contains("confidence sequence of A − B"), "{text}");
    }

    /// The replay prints the race page's fixed-size comparison of the
    /// pairs used: the exact McNemar interval and p-value, and the note
    /// that neither holds after the data-dependent stop.
    #[test]
    fn the_replay_prints_the_fixed_size_comparison_the_race_page_shows() {
        let mut pairs = vec![(true, false); 40];
        pairs.extend([(false, true); 5]);
        pairs.extend([(true, true); 155]);
        let r = d3il_metrics::sequential::replay(&pairs, 0.05, None, 3);
        let text = super::race_replay(&r);
        let f = d3il_metrics::rate_difference::ExactMcNemar::new(
            r.pairs_used as usize,
            r.discordant.0,
            r.discordant.1,
        )
        .paired_interval(0.95);
        let i = f.interval.expect("an interval");
        assert!(
            text.contains(&format!(
                "Fixed-size comparison of the {} pairs used: A − B {:+.3}, 95 % interval {:.3}–{:.3}",
                r.pairs_used, f.estimate, i.low, i.high
            )),
            "{text}"
        );
        assert!(
            text.contains(&format!("exact McNemar p-value {:.4}", f.p_value)),
            "{text}"
        );
        assert!(
            text.contains("neither is valid after the race's data-dependent stop"),
            "{text}"
        );
    }
}
