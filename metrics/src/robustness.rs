//! The robustness track's score: success retained, averaged over
//! an axis's levels (the axis's score) and over the axes (the overall
//! score). Success retained is paired by initial state and bounded to
//! [0, 1]: `Σ_s min(p0(s), pL(s)) / Σ_s p0(s)`, with `p0(s)` and `pL(s)`
//! the success rates of state `s` at level 0 and at the level: the share of
//! level 0's successes the level keeps. A level that does better than level
//! 0 on some states does not make up there for what it loses on others (the
//! plain ratio of success rates did, and exceeded 1); the net change, gains
//! included, is the paired drop. Its interval is the
//! paired bootstrap of [`crate::compare`]: initial states resampled, the same
//! picks for level 0 and every level, and the same bias-corrected percentile
//! interval. The per-level drops themselves are [`crate::compare`]'s.

use crate::{bias_corrected_interval, Bootstrap, MetricsError};
use d3il_protocol::{ContextResult, Estimate};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Scores of one robustness evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct Scores {
    /// Per level (in the order given): success retained, None when level 0
    /// has no success.
    pub retained: Vec<Option<f64>>,
    /// Per axis (0..n_axes): the mean of its levels' success retained.
    pub axes: Vec<Option<Estimate>>,
    /// The mean of the axes' scores.
    pub overall: Option<Estimate>,
}

/// `control` is level 0's per-state breakdown, `levels` each perturbed
/// level's with the index of its axis (below `n_axes`). Every breakdown must
/// list the same initial states.
pub fn robustness_scores(
    control: &[ContextResult],
    levels: &[(usize, &[ContextResult])],
    n_axes: usize,
    cfg: &Bootstrap,
) -> Result<Scores, MetricsError> {
    if control.is_empty() {
        return Err(MetricsError::NoOutcomes);
    }
    if !(cfg.confidence > 0.0 && cfg.confidence < 1.0) {
        return Err(MetricsError::BadConfidence(cfg.confidence));
    }
    let states: Vec<usize> = control.iter().map(|c| c.context_index).collect();
    for (axis, l) in levels {
        if *axis >= n_axes {
            return Err(MetricsError::NotComparable(format!(
                "a level names axis {axis} of {n_axes}"
            )));
        }
        if l.iter().map(|c| c.context_index).ne(states.iter().copied()) {
            return Err(MetricsError::NotComparable(
                "a level's per-state breakdown lists other initial states than level 0's".into(),
            ));
        }
    }
    let n = control.len();
    let base_sum = |picks: &[usize]| picks.iter().map(|&i| control[i].success_rate).sum::<f64>();
    let kept = |l: &[ContextResult], picks: &[usize]| {
        picks
            .iter()
            .map(|&i| l[i].success_rate.min(control[i].success_rate))
            .sum::<f64>()
    };
    // (per level retained, per axis score, overall) for one selection of states.
    type Selection = (Vec<f64>, Vec<Option<f64>>, Option<f64>);
    let score = |picks: &[usize]| -> Option<Selection> {
        let base = base_sum(picks);
        if base <= 0.0 {
            return None;
        }
        let retained: Vec<f64> = levels.iter().map(|(_, l)| kept(l, picks) / base).collect();
        let axes: Vec<Option<f64>> = (0..n_axes)
            .map(|a| {
                let v: Vec<f64> = levels
                    .iter()
                    .zip(&retained)
                    .filter(|((axis, _), _)| *axis == a)
                    .map(|(_, r)| *r)
                    .collect();
                (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
            })
            .collect();
        let scored: Vec<f64> = axes.iter().flatten().copied().collect();
        let overall =
            (!scored.is_empty()).then(|| scored.iter().sum::<f64>() / scored.len() as f64);
        Some((retained, axes, overall))
    };
    let all: Vec<usize> = (0..n).collect();
    let Some((retained, axes, overall)) = score(&all) else {
        return Ok(Scores {
            retained: vec![None; levels.len()],
            axes: vec![None; n_axes],
            overall: None,
        });
    };
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    let mut boot_axes: Vec<Vec<f64>> = vec![Vec::new(); n_axes];
    let mut boot_overall = Vec::new();
    let mut picks = vec![0usize; n];
    for _ in 0..cfg.resamples {
        for p in picks.iter_mut() {
            *p = rng.random_range(0..n as u64) as usize;
        }
        // A resample whose level 0 has no success has no score.
        if let Some((_, a, o)) = score(&picks) {
            for (k, v) in a.iter().enumerate() {
                if let Some(v) = v {
                    boot_axes[k].push(*v);
                }
            }
            if let Some(o) = o {
                boot_overall.push(o);
            }
        }
    }
    let bounds = (0.0, 1.0);
    Ok(Scores {
        retained: retained.into_iter().map(Some).collect(),
        axes: axes
            .iter()
            .zip(boot_axes.iter_mut())
            .map(|(v, b)| v.map(|v| bias_corrected_interval(v, b, cfg.confidence, bounds)))
            .collect(),
        overall: overall
            .map(|v| bias_corrected_interval(v, &mut boot_overall, cfg.confidence, bounds)),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn states(rates: &[f64]) -> Vec<ContextResult> {
        rates
            .iter()
            .enumerate()
            .map(|(i, &r)| ContextResult {
                context_index: i,
                success_rate: r,
                conditional_entropy: 0.0,
                behaviours: vec![],
            })
            .collect()
    }

    #[test]
    fn retained_is_averaged_over_levels_and_axes() {
        let control = states(&[1.0, 1.0, 0.0, 1.0]);
        let half = states(&[1.0, 0.0, 0.0, 0.5]);
        let same = states(&[1.0, 1.0, 0.0, 1.0]);
        let levels = [(0, &half[..]), (0, &same[..]), (1, &same[..])];
        let s = robustness_scores(&control, &levels, 2, &Bootstrap::default()).unwrap();
        assert_eq!(s.retained, vec![Some(0.5), Some(1.0), Some(1.0)]);
        let a0 = s.axes[0].unwrap();
        assert!((a0.value - 0.75).abs() < 1e-12 && a0.ci_low <= 0.75 && a0.ci_high >= 0.75);
        assert_eq!(s.axes[1].unwrap().value, 1.0);
        assert!((s.overall.unwrap().value - 0.875).abs() < 1e-12);
        // Gains on one state do not make up for losses on another.
        let swapped = states(&[0.0, 1.0, 1.0, 1.0]);
        let s =
            robustness_scores(&control, &[(0, &swapped[..])], 1, &Bootstrap::default()).unwrap();
        assert!((s.retained[0].unwrap() - 2.0 / 3.0).abs() < 1e-12);
        let better = states(&[1.0, 1.0, 1.0, 1.0]);
        let s = robustness_scores(&control, &[(0, &better[..])], 1, &Bootstrap::default()).unwrap();
        assert_eq!(s.retained[0], Some(1.0), "bounded by 1");
        assert!(s.axes[0].unwrap().ci_high <= 1.0);
        let none = states(&[0.0; 4]);
        let s = robustness_scores(&none, &levels, 2, &Bootstrap::default()).unwrap();
        assert_eq!((s.retained[0], s.axes[0], s.overall), (None, None, None));
    }
}
