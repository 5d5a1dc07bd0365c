//! Paired comparison of two results on the same initial states.
//!
//! Every evaluation runs the same fixed initial states, so two policies can be
//! compared state by state: the difference in success rate (and in conditional
//! entropy) is a mean over states of per-state differences, and the
//! state-to-state variation that dominates an unpaired comparison cancels.
//!
//! * **Success rate**: the test its design calls for and that test inverted
//!   as the interval ([`crate::rate_difference::success_rate_difference`]):
//!   the exact McNemar test with one rollout a state, a two-sample score
//!   test of the rollouts with one initial state, the paired randomisation
//!   (sign-flip) test otherwise. The p-value printed is the one of the test
//!   whose inversion is the interval, so "0 outside" and "p ≤ α" agree by
//!   construction. No interval with 5 states or fewer (except one: two
//!   samples), or, for the sign-flip test, when every state shows the same
//!   difference.
//! * **Conditional entropy of Avoiding, Aligning, Pushing** (a state without
//!   a labelled success counts as 0): the paired randomisation test, A and B
//!   swapped within each state (the per-state difference sign-flipped), and
//!   its inversion ([`crate::intervals::SignFlip`]).
//! * **Conditional entropy of Sorting, Stacking, Inserting** (states without
//!   a labelled success dropped, so the statistic is not a mean of per-state
//!   differences): paired bootstrap over initial states (the same resampled
//!   states for A and B), bias-corrected percentile interval as in
//!   [`crate::bootstrap_all`], and the swap test's p-value,
//!   `p = (1 + #{|d_swapped| ≥ |d|}) / (1 + R)`; the two can disagree and
//!   the interval's method ([`IntervalMethod::PairedBootstrap`]) says so.
//! * **Minimum detectable difference**: `(z_{1−α/2} + z_{0.8}) · se`, with the
//!   paired bootstrap standard error `se` at this protocol's size (states ×
//!   rollouts): the smallest true difference the comparison finds with 80 %
//!   power at level α = 1 − confidence.

pub use crate::quantile::normal_quantile;
use crate::{bias_corrected_interval, Bootstrap, EmptyContexts, EntropyConvention, MetricsError};
use d3il_protocol::{
    Comparison, ContextResult, Estimate, EvalResult, IntervalMethod, ObsType, PairedDifference,
    ProtocolManifest, RobotLook,
};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// What a comparison needs of one initial state of one result.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContextSummary {
    pub success_rate: f64,
    /// The state's entropy as the reference computes it; `None` when the state
    /// has no labelled success.
    pub entropy: Option<f64>,
}

impl ContextSummary {
    pub fn from_result(c: &ContextResult) -> Self {
        let labelled: usize = c.behaviours.iter().map(|(_, n)| n).sum();
        ContextSummary {
            success_rate: c.success_rate,
            entropy: (labelled > 0).then_some(c.conditional_entropy),
        }
    }
}

/// Success rate and conditional entropy of a selection of states (with
/// repetition), under the task's rule for states without a labelled success.
fn stats<'a>(states: impl Iterator<Item = &'a ContextSummary>, empty: EmptyContexts) -> [f64; 2] {
    let (mut n, mut sr, mut h, mut hn) = (0usize, 0.0, 0.0, 0usize);
    for s in states {
        n += 1;
        sr += s.success_rate;
        match s.entropy {
            Some(e) => {
                h += e;
                hn += 1;
            }
            None if empty == EmptyContexts::CountAsZero => hn += 1,
            None => {}
        }
    }
    [
        if n == 0 { 0.0 } else { sr / n as f64 },
        if hn == 0 { 0.0 } else { h / hn as f64 },
    ]
}

/// Paired comparison of per-state summaries `a[i]`, `b[i]` (same state i),
/// each state's success rate the share of `rollouts_per_state` rollouts.
/// Returns (success rate, conditional entropy).
pub fn compare_states(
    a: &[ContextSummary],
    b: &[ContextSummary],
    rollouts_per_state: usize,
    empty: EmptyContexts,
    cfg: &Bootstrap,
) -> Result<[PairedDifference; 2], MetricsError> {
    if a.is_empty() {
        return Err(MetricsError::NoOutcomes);
    }
    if a.len() != b.len() {
        return Err(MetricsError::NotComparable(format!(
            "A has {} initial states and B has {}",
            a.len(),
            b.len()
        )));
    }
    if !(cfg.confidence > 0.0 && cfg.confidence < 1.0) {
        return Err(MetricsError::BadConfidence(cfg.confidence));
    }
    let n = a.len();
    let sa = stats(a.iter(), empty);
    let sb = stats(b.iter(), empty);
    let d = [sa[0] - sb[0], sa[1] - sb[1]];
    let mut rng = ChaCha8Rng::seed_from_u64(cfg.seed);
    // Paired bootstrap over states.
    let mut boot: [Vec<f64>; 2] = [Vec::new(), Vec::new()];
    let mut picks = vec![0usize; n];
    for _ in 0..cfg.resamples {
        for p in picks.iter_mut() {
            *p = rng.random_range(0..n as u64) as usize;
        }
        let ra = stats(picks.iter().map(|&i| &a[i]), empty);
        let rb = stats(picks.iter().map(|&i| &b[i]), empty);
        boot[0].push(ra[0] - rb[0]);
        boot[1].push(ra[1] - rb[1]);
    }
    // Randomisation test: swap A and B within states.
    let mut extreme = [0usize; 2];
    let mut swap = vec![false; n];
    for _ in 0..cfg.resamples {
        for s in swap.iter_mut() {
            *s = rng.random_bool(0.5);
        }
        let pa = stats((0..n).map(|i| if swap[i] { &b[i] } else { &a[i] }), empty);
        let pb = stats((0..n).map(|i| if swap[i] { &a[i] } else { &b[i] }), empty);
        for k in 0..2 {
            // A tolerance so that float noise in a recomputed equal mean
            // does not count as "less extreme".
            if (pa[k] - pb[k]).abs() >= d[k].abs() - 1e-12 {
                extreme[k] += 1;
            }
        }
    }
    let z = normal_quantile(1.0 - (1.0 - cfg.confidence) / 2.0) + normal_quantile(0.8);
    let se = |boot: &[f64]| {
        let r = boot.len();
        if r > 1 {
            let m = boot.iter().sum::<f64>() / r as f64;
            (boot.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (r - 1) as f64).sqrt()
        } else {
            0.0
        }
    };
    // Per-state values whose mean is the statistic and whose sign-flip is
    // the swap of A and B within a state: the success rates always, the
    // entropies when states without a labelled success count as 0.
    let paired = |value: fn(&ContextSummary) -> f64| {
        let da: Vec<f64> = a.iter().map(value).collect();
        let db: Vec<f64> = b.iter().map(value).collect();
        crate::intervals::paired_difference_interval(
            &da,
            &db,
            cfg.confidence,
            cfg.resamples,
            cfg.seed,
        )
    };
    let [b0, mut b1] = boot;
    let rates = crate::rate_difference::success_rate_difference(
        &a.iter().map(|s| s.success_rate).collect::<Vec<_>>(),
        &b.iter().map(|s| s.success_rate).collect::<Vec<_>>(),
        rollouts_per_state,
        cfg.confidence,
        cfg.resamples,
        cfg.seed,
    );
    let success_rate = PairedDifference {
        a: sa[0],
        b: sb[0],
        difference: Estimate {
            value: d[0],
            ..rates.to_estimate()
        },
        p_value: rates.p_value,
        min_detectable: z * se(&b0),
    };
    let conditional_entropy = if empty == EmptyContexts::CountAsZero {
        let h = paired(|s| s.entropy.unwrap_or(0.0));
        PairedDifference {
            a: sa[1],
            b: sb[1],
            difference: Estimate {
                value: d[1],
                ..h.to_estimate()
            },
            p_value: h.p_value,
            min_detectable: z * se(&b1),
        }
    } else {
        // The mean over states with a labelled success is not a mean of
        // per-state differences: the swap test above (`extreme`) and a
        // paired bootstrap, which can disagree (the method says so).
        let se1 = se(&b1);
        // Both entropies lie in [0, 1] (see `bootstrap_all`), so does |A − B|.
        let e = bias_corrected_interval(d[1], &mut b1, cfg.confidence, (-1.0, 1.0));
        PairedDifference {
            a: sa[1],
            b: sb[1],
            difference: Estimate {
                method: e
                    .no_interval
                    .is_none()
                    .then_some(IntervalMethod::PairedBootstrap),
                ..e
            },
            p_value: (1 + extreme[1]) as f64 / (1 + cfg.resamples) as f64,
            min_detectable: z * se1,
        }
    };
    Ok([success_rate, conditional_entropy])
}

/// Paired comparison of two evaluation results (A − B): same task, protocol,
/// initial-state set and protocol size, else [`MetricsError::NotComparable`]
/// naming what differs.
pub fn compare(
    a: &EvalResult,
    b: &EvalResult,
    cfg: &Bootstrap,
) -> Result<Comparison, MetricsError> {
    compare_parts(
        (&a.manifest, &a.per_context),
        (&b.manifest, &b.per_context),
        cfg,
    )
}

/// [`compare`] from what a stored result keeps: its manifest and per-state
/// breakdown.
pub fn compare_parts(
    a: (&ProtocolManifest, &[ContextResult]),
    b: (&ProtocolManifest, &[ContextResult]),
    cfg: &Bootstrap,
) -> Result<Comparison, MetricsError> {
    let ((ma, pa), (mb, pb)) = (a, b);
    check_comparable(ma, mb)?;
    let ia: Vec<usize> = pa.iter().map(|c| c.context_index).collect();
    let ib: Vec<usize> = pb.iter().map(|c| c.context_index).collect();
    if ia != ib {
        return Err(MetricsError::NotComparable(
            "their per-state breakdowns list different initial states".into(),
        ));
    }
    let sa: Vec<ContextSummary> = pa.iter().map(ContextSummary::from_result).collect();
    let sb: Vec<ContextSummary> = pb.iter().map(ContextSummary::from_result).collect();
    let empty = EntropyConvention::for_task(ma.task).empty_contexts;
    let [success_rate, conditional_entropy] =
        compare_states(&sa, &sb, ma.rollouts_per_context, empty, cfg)?;
    Ok(Comparison {
        task: ma.task,
        protocol: ma.protocol,
        initial_states: ma.initial_states_name(),
        initial_states_sha256: ma.initial_states_sha256.clone(),
        n_contexts: ma.n_contexts,
        rollouts_per_context: ma.rollouts_per_context,
        resamples: cfg.resamples,
        confidence: cfg.confidence,
        success_rate,
        conditional_entropy,
        caveats: caveats(ma, mb),
    })
}

/// Whether two results can be compared pair by pair: same task, protocol,
/// initial-state set and size, else [`MetricsError::NotComparable`] naming
/// what differs.
pub fn check_comparable(ma: &ProtocolManifest, mb: &ProtocolManifest) -> Result<(), MetricsError> {
    let differ = |what: &str, x: String, y: String| -> Result<(), MetricsError> {
        if x != y {
            return Err(MetricsError::NotComparable(format!(
                "they differ in {what}: A has {x}, B has {y}; a paired comparison needs two results of the same task, protocol and initial states"
            )));
        }
        Ok(())
    };
    differ("task", ma.task.to_string(), mb.task.to_string())?;
    differ(
        "protocol",
        format!("{:?}", ma.protocol),
        format!("{:?}", mb.protocol),
    )?;
    differ(
        "initial-state set",
        format!(
            "{} (sha256 {})",
            ma.initial_states_name(),
            ma.initial_states_sha256
        ),
        format!(
            "{} (sha256 {})",
            mb.initial_states_name(),
            mb.initial_states_sha256
        ),
    )?;
    differ(
        "size",
        format!("{} × {} rollouts", ma.n_contexts, ma.rollouts_per_context),
        format!("{} × {} rollouts", mb.n_contexts, mb.rollouts_per_context),
    )?;
    Ok(())
}

/// What differs between two results that [`compare_parts`] pairs anyway: the
/// environment and its initial states are the same, but the difference then
/// also measures these.
fn caveats(a: &ProtocolManifest, b: &ProtocolManifest) -> Vec<String> {
    let mut out = vec![];
    if a.obs_type != b.obs_type {
        out.push(format!(
            "A observes the {} and B the {}: the difference is between the two observation set-ups as well as the policies",
            observes(a.obs_type),
            observes(b.obs_type)
        ));
    } else if a.obs_type == ObsType::Image && a.robot_look != b.robot_look {
        let drawn = |l: Option<RobotLook>| match l {
            Some(RobotLook::Meshes) => "with the Panda's meshes",
            Some(RobotLook::Primitives) => "with primitive shapes",
            None => "in a way not recorded",
        };
        out.push(format!(
            "A's camera frames drew the robot {} and B's {}: the difference includes how the robot was drawn",
            drawn(a.robot_look),
            drawn(b.robot_look)
        ));
    }
    if a.physics_fingerprint() != b.physics_fingerprint() {
        let fp = |m: &ProtocolManifest| {
            m.physics_fingerprint()
                .map(|f| format!("physics fingerprint {f}"))
                .unwrap_or_else(|| {
                    "no physics fingerprint (made before builds were identified)".into()
                })
        };
        out.push(format!(
            "A and B were made by builds that may simulate differently (A: {}; B: {}): the difference includes the simulators'",
            fp(a),
            fp(b)
        ));
    }
    out
}

fn observes(obs: ObsType) -> &'static str {
    match obs {
        ObsType::State => "state",
        ObsType::Image => "camera images",
    }
}

/// Wilson score interval of `successes` out of `n` at two-sided level
/// `1 - alpha` (0.05: 95 %), the interval of a success rate measured on
/// independent rollouts without per-state structure (the fidelity report
/// uses it for results recorded in the original simulator). `(0, 1)` for
/// `n = 0`.
pub fn wilson_interval(successes: usize, n: usize, alpha: f64) -> (f64, f64) {
    if n == 0 {
        return (0.0, 1.0);
    }
    let z = normal_quantile(1.0 - alpha / 2.0);
    let (k, n) = (successes as f64, n as f64);
    let p = k / n;
    let z2 = z * z;
    let centre = (p + z2 / (2.0 * n)) / (1.0 + z2 / n);
    let half = z / (1.0 + z2 / n) * (p * (1.0 - p) / n + z2 / (4.0 * n * n)).sqrt();
    ((centre - half).max(0.0), (centre + half).min(1.0))
}

#[cfg(test)]
mod wilson_tests {
    #[test]
    fn wilson_matches_published_values() {
        // 30/60 and 19/30 (the reference closed-loop README's intervals).
        let (lo, hi) = super::wilson_interval(30, 60, 0.05);
        assert!(
            (lo - 0.3773).abs() < 1e-3 && (hi - 0.6227).abs() < 1e-3,
            "{lo} {hi}"
        );
        let (lo, hi) = super::wilson_interval(19, 30, 0.05);
        assert!(
            (lo - 0.4551).abs() < 1e-3 && (hi - 0.7813).abs() < 1e-3,
            "{lo} {hi}"
        );
        assert_eq!(super::wilson_interval(0, 0, 0.05), (0.0, 1.0));
        let (lo, _) = super::wilson_interval(0, 10, 0.05);
        assert_eq!(lo, 0.0);
    }
}
