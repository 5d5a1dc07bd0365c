//! Results made before 0.5.0 brought to this version's intervals (docs/intervals.md)
//! from what they keep: per-rollout records (success, and for Stacking the
//! registration order) and the per-state breakdown. What the server runs on
//! every stored result at start-up and `d3il intervals recompute` runs on
//! documents.
//!
//! * success rates (Stacking: each level's) get [`crate::intervals`]'s
//!   interval from the records, seeded as the evaluation was (the manifest's
//!   seed; the resamples only matter at 100 states or more);
//! * entropies keep their values and bootstrap intervals, with the one
//!   change 0.5.0 made there: residues below 1e-12 of the reference's
//!   guards are exact zeros (`exact_zero`), and the method is named;
//! * paired drops of a robustness document are computed again from the
//!   recomputed level results, as [`crate::suite_shard::document`] makes
//!   them, and with them the scores.
//!
//! The values of success rates and entropies above 1e-12 are kept as
//! stored; intervals and p-values move.

use crate::intervals::{state_counts, task_success_estimate, StateCount};
use crate::suite_shard::{document, SuiteLevels};
use crate::MetricsError;
use d3il_protocol::perturbation::Perturbation;
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::{Estimate, EvalResult, IntervalMethod, TaskId};

/// The bootstrap resamples evaluations run with (`d3il eval`'s default);
/// used by the success-rate rule only at 100 states or more.
pub const RESAMPLES: usize = 1000;

/// This version's interval rules (docs/intervals.md); stored next to results so that
/// the server recomputes those made under an earlier rule.
pub const RULES_VERSION: i64 = 2;

/// The interval rules a result (its `manifest` and `metrics`) was computed
/// under: builds before 0.5.0 never named a success rate's method or why it
/// has none (`None`: recompute); 0.5 builds followed rules 1 (the sign-flip
/// interval for every paired drop); later ones this build's
/// [`RULES_VERSION`] (the exact McNemar and two-sample score intervals).
pub fn rules_of(
    manifest: &d3il_protocol::ProtocolManifest,
    m: &d3il_protocol::Metrics,
) -> Option<i64> {
    if m.success_rate.method.is_none() && m.success_rate.no_interval.is_none() {
        return None;
    }
    let mut parts = manifest
        .evaluator_version
        .split('.')
        .map(|x| x.parse::<u64>().unwrap_or(0));
    let (major, minor) = (parts.next().unwrap_or(0), parts.next().unwrap_or(0));
    Some(if (major, minor) <= (0, 5) {
        1
    } else {
        RULES_VERSION
    })
}

fn entropy(e: &mut Estimate) {
    for x in [&mut e.value, &mut e.ci_low, &mut e.ci_high] {
        *x = crate::exact_zero(*x);
    }
    if e.method.is_none() && e.no_interval.is_none() {
        e.method = Some(IntervalMethod::BiasCorrectedBootstrap);
    }
}

/// `r`'s intervals as this version computes them (see the module docs).
pub fn recompute_intervals(r: &mut EvalResult) -> Result<(), MetricsError> {
    let task = r.manifest.task;
    let seed = r.manifest.seed;
    if r.rollouts.is_empty() {
        // A summary without records: the per-state breakdown holds each
        // state's rate of its `rollouts_per_context` rollouts (Stacking:
        // Stacking-3's only).
        if task == TaskId::Stacking || r.per_context.is_empty() {
            return Err(MetricsError::Records(
                "the document has no rollout records to recompute its intervals from".into(),
            ));
        }
        let m = r.manifest.rollouts_per_context.max(1) as u32;
        let states: Vec<StateCount> = r
            .per_context
            .iter()
            .map(|c| StateCount::new((c.success_rate * m as f64).round() as u32, m))
            .collect();
        let e = task_success_estimate(task, &states, 0.95, RESAMPLES, seed);
        r.metrics.success_rate = keep_value(e, r.metrics.success_rate.value);
        finish_entropies(r);
        return Ok(());
    }
    let success = |level: &dyn Fn(&d3il_protocol::RolloutRecord) -> bool, seed: u64| -> Estimate {
        let states = state_counts(r.rollouts.iter().map(|x| (x.context_index, level(x))));
        task_success_estimate(task, &states, 0.95, RESAMPLES, seed)
    };
    let m = &mut r.metrics;
    if task == TaskId::Stacking {
        // Level X (1, 2) succeeds when X boxes registered: the order string's
        // length (`crate::stacking_levels`); level 3 on the full stack.
        let order_len = |x: &d3il_protocol::RolloutRecord| -> Result<usize, MetricsError> {
            x.behaviour.as_str().map(str::len).ok_or_else(|| {
                MetricsError::Records(format!(
                    "Stacking rollout {} of initial state {} has behaviour {} where a registration order string was expected",
                    x.rollout_index, x.context_index, x.behaviour
                ))
            })
        };
        for x in &r.rollouts {
            order_len(x)?;
        }
        let rates: [Estimate; 3] = [
            // The seeds `evaluate` gives the levels.
            success(&|x| order_len(x).unwrap_or(0) >= 1, seed),
            success(&|x| order_len(x).unwrap_or(0) >= 2, seed.wrapping_add(10)),
            success(&|x| x.success, seed.wrapping_add(20)),
        ];
        if let Some(levels) = m.stacking_levels.as_mut() {
            for (l, rate) in levels.iter_mut().zip(rates) {
                l.success_rate = keep_value(rate, l.success_rate.value);
                entropy(&mut l.behaviour_entropy);
                entropy(&mut l.conditional_entropy);
            }
        }
        m.success_rate = keep_value(rates[2], m.success_rate.value);
    } else {
        m.success_rate = keep_value(success(&|x| x.success, seed), m.success_rate.value);
    }
    finish_entropies(r);
    Ok(())
}

/// `new`'s interval (or reason) around the stored value: intervals are
/// recomputed, values are not (the records give the same value for every
/// result an evaluation made).
fn keep_value(new: Estimate, stored: f64) -> Estimate {
    match new.interval() {
        Some((lo, hi)) => Estimate {
            value: stored,
            ci_low: lo.min(stored),
            ci_high: hi.max(stored),
            ..new
        },
        None => Estimate {
            value: stored,
            ci_low: stored,
            ci_high: stored,
            ..new
        },
    }
}

fn finish_entropies(r: &mut EvalResult) {
    entropy(&mut r.metrics.behaviour_entropy);
    entropy(&mut r.metrics.conditional_entropy);
    for c in &mut r.per_context {
        c.conditional_entropy = crate::exact_zero(c.conditional_entropy);
    }
}

/// A robustness document's results, drops and scores as this version
/// computes them.
pub fn recompute_robustness(doc: &mut RobustnessResult) -> Result<(), MetricsError> {
    let mut control = doc.control.clone();
    recompute_intervals(&mut control)?;
    let suite = SuiteLevels {
        name: doc.suite.clone(),
        sha256: doc.suite_sha256.clone(),
        axes: doc.axes.iter().map(|a| a.axis).collect(),
        levels: Vec::new(),
    };
    let mut results = Vec::with_capacity(doc.levels.len());
    for l in &doc.levels {
        let mut r = l.result.clone();
        recompute_intervals(&mut r)?;
        let p = Perturbation {
            suite: doc.suite.clone(),
            suite_sha256: doc.suite_sha256.clone(),
            axis: l.axis,
            level: l.level,
            setting: l.setting.clone(),
        };
        results.push((p, r));
    }
    let seed = control.manifest.seed;
    let mut fresh = document(&suite, control, results, seed)?;
    fresh.format = doc.format.clone();
    *doc = fresh;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read<T: serde::de::DeserializeOwned>(path: &str) -> T {
        let p = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("..")
            .join(path);
        serde_json::from_slice(&std::fs::read(&p).unwrap()).unwrap()
    }

    #[test]
    fn a_robustness_document_of_0_4_gets_this_versions_intervals_and_keeps_its_values() {
        // Pushing BC under the paper protocol (30 states × 2 rollouts a
        // level), stored without rollout records: rates from the per-state
        // breakdown. Issue 51 quoted its start_shift +50 % drop: interval
        // [0.001, 0.351] beside p 0.064.
        let old: RobustnessResult =
            read("docs/measurements/robustness-2026-11-29/pushing-v2_push_bc_noise_paper-2-per-state.json");
        assert_eq!(rules_of(&old.control.manifest, &old.control.metrics), None);
        let mut doc = old.clone();
        recompute_robustness(&mut doc).unwrap();
        // Recomputed, it names its methods (the upgrade stores it under
        // RULES_VERSION; its manifest keeps the 0.4 build that made it).
        assert_eq!(
            rules_of(&doc.control.manifest, &doc.control.metrics),
            Some(1)
        );
        assert_eq!(
            doc.control.metrics.success_rate.method,
            Some(IntervalMethod::KornGraubard)
        );
        for (a, b) in old.levels.iter().zip(&doc.levels) {
            let (x, y) = (&a.paired.success_rate, &b.paired.success_rate);
            assert_eq!(x.difference.value, y.difference.value);
            assert_eq!(
                a.result.metrics.success_rate.value,
                b.result.metrics.success_rate.value
            );
            let (lo, hi) = y.difference.interval().expect("30 states: an interval");
            assert_eq!(lo > 0.0 || hi < 0.0, y.p_value <= 0.05, "{:?}", b.setting);
            assert!(hi > lo);
        }
        let shift = doc
            .levels
            .iter()
            .find(|l| l.axis.to_string() == "start_shift" && l.level == 1)
            .unwrap();
        let d = &shift.paired.success_rate;
        assert!(
            d.p_value > 0.05 && d.difference.interval().unwrap().0 <= 0.0,
            "{d:?}"
        );
    }

    #[test]
    fn a_one_rollout_suites_drops_get_the_exact_mcnemar_interval() {
        // The scripted Pushing expert, 30 states × 1 rollout a level, rates
        // near 1: where the sign-flip interval covered 66–93 % in the bench.
        // Now the exact McNemar test and its interval, which agree, and an
        // interval even where every state shows the same difference.
        let mut doc: RobustnessResult = read(
            "docs/measurements/robustness-2026-11-29/pushing-v2_scripted-pushing-all-modes_paper-1-per-state.json",
        );
        recompute_robustness(&mut doc).unwrap();
        assert!(!doc.levels.is_empty());
        for l in &doc.levels {
            let d = &l.paired.success_rate;
            assert_eq!(
                d.difference.method,
                Some(IntervalMethod::McNemarExact),
                "{:?}",
                l.setting
            );
            let (lo, hi) = d.difference.interval().expect("30 states: an interval");
            assert!(hi > lo && lo <= d.difference.value && d.difference.value <= hi);
            assert_eq!(
                lo > 0.0 || hi < 0.0,
                d.p_value <= 0.05,
                "{:?} {d:?}",
                l.setting
            );
        }
    }

    #[test]
    fn a_result_keeps_its_values_and_gets_its_interval_from_its_records() {
        // Avoiding BC (one initial state, its rollouts all succeed): the
        // old interval was [1, 1]; now Clopper-Pearson on the rollouts.
        let old: EvalResult = read("server/tests/fixtures/zoo/avoiding/bc-mlp-s0/result.json");
        let mut r = old.clone();
        recompute_intervals(&mut r).unwrap();
        let (a, b) = (&old.metrics, &r.metrics);
        assert_eq!(a.success_rate.value, b.success_rate.value);
        assert_eq!(
            b.success_rate.method,
            Some(IntervalMethod::ClopperPearsonRollouts)
        );
        let n = r.rollouts.len() as f64;
        let k = r.rollouts.iter().filter(|x| x.success).count() as f64;
        let (lo, hi) = crate::intervals::clopper_pearson(k, n, 0.05);
        assert_eq!(
            b.success_rate.interval(),
            Some((lo.min(k / n), hi.max(k / n)))
        );
        assert_eq!(b.behaviour_entropy.value, a.behaviour_entropy.value);
        assert_eq!(
            b.behaviour_entropy.method,
            Some(IntervalMethod::BiasCorrectedBootstrap)
        );
        // Its suite's drops: one initial state, so the rollouts of level 0
        // and of the level are two samples: the score test and its interval.
        let mut doc: RobustnessResult =
            read("server/tests/fixtures/zoo/avoiding/bc-mlp-s0/robustness.json");
        recompute_robustness(&mut doc).unwrap();
        let m = doc.control.manifest.rollouts_per_context as u64;
        let mut rejected = 0;
        for l in &doc.levels {
            let d = &l.paired.success_rate;
            assert_eq!(d.difference.method, Some(IntervalMethod::ScoreTwoSample));
            let k = |r: f64| (r * m as f64).round() as u64;
            let t = crate::rate_difference::ScoreTwoSample::new(k(d.a), m, k(d.b), m);
            assert_eq!(d.p_value, t.p_value(0.0), "{:?}", l.setting);
            let (lo, hi) = d.difference.interval().expect("two samples: an interval");
            assert!(hi > lo, "{:?} {d:?}", l.setting);
            assert_eq!(
                lo > 0.0 || hi < 0.0,
                d.p_value <= 0.05,
                "{:?} {d:?}",
                l.setting
            );
            rejected += (d.p_value <= 0.05) as usize;
        }
        eprintln!("{rejected} of {} levels differ at 5 %", doc.levels.len());
    }
}
