//! Hand-computed values; each comment shows the arithmetic.

use super::*;

fn o(c: usize, s: bool, b: Option<&str>) -> Outcome {
    Outcome::new(c, s, b)
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-9
}

#[test]
fn success_rate_counts_all_rollouts() {
    let v = [
        o(0, true, None),
        o(0, false, Some("1")),
        o(1, true, Some("0")),
        o(1, false, None),
    ];
    assert_eq!(success_rate(&v), 0.5);
    assert_eq!(success_rate(&[]), 0.0);
}

#[test]
fn avoiding_entropy_over_successes_log24() {
    // Successes: 138, 138, 37, 37 → p = (1/2, 1/2) → H = ln 2 / ln 24 = 0.2181...
    // The failure with code 37 is ignored.
    let v = [
        o(0, true, Some("138")),
        o(0, true, Some("138")),
        o(0, true, Some("37")),
        o(0, true, Some("37")),
        o(0, false, Some("37")),
    ];
    let expected = 2f64.ln() / 24f64.ln();
    assert!(close(behaviour_entropy(&v, 24).unwrap(), expected));
    let conv = EntropyConvention::for_task(TaskId::Avoiding);
    // Single start: the conditional entropy is the marginal one (docs/original-d3il.md §10.2.6).
    assert!(close(conditional_entropy(&v, &conv).unwrap(), expected));
    assert!((expected - 0.218104).abs() < 1e-6);
}

#[test]
fn avoiding_counts_codes_with_missed_rows_and_may_exceed_one() {
    // 30 distinct codes, one success each: H = ln 30 / ln 24 = 1.0702 > 1
    // (docs/original-d3il.md §10.6.4: the reference does not guard against this).
    let labels: Vec<String> = (0..30).map(|i| format!("{i}")).collect();
    let v: Vec<Outcome> = labels.iter().map(|l| o(0, true, Some(l))).collect();
    let h = behaviour_entropy(&v, 24).unwrap();
    assert!(close(h, 30f64.ln() / 24f64.ln()));
    assert!(h > 1.0);
}

#[test]
fn no_success_gives_zero_entropy() {
    let v = [o(0, false, Some("1")), o(1, false, Some("2"))];
    assert_eq!(behaviour_entropy(&v, 2).unwrap(), 0.0);
    for t in [TaskId::Aligning, TaskId::Sorting4] {
        assert_eq!(
            conditional_entropy(&v, &EntropyConvention::for_task(t)).unwrap(),
            0.0
        );
    }
}

/// Three contexts × 4 rollouts:
/// c0: successes with modes 0, 0, 1, 1 → H_0 = 1 (log 2)
/// c1: successes 0, 0, 0 and one failure → H_1 = 0
/// c2: no success
fn three_contexts() -> Vec<Outcome> {
    vec![
        o(0, true, Some("0")),
        o(0, true, Some("0")),
        o(0, true, Some("1")),
        o(0, true, Some("1")),
        o(1, true, Some("0")),
        o(1, true, Some("0")),
        o(1, true, Some("0")),
        o(1, false, Some("1")),
        o(2, false, Some("0")),
        o(2, false, Some("1")),
        o(2, false, Some("0")),
        o(2, false, Some("1")),
    ]
}

#[test]
fn aligning_counts_contexts_without_success_as_zero() {
    // (1 + 0 + 0) / 3 = 1/3 (docs/original-d3il.md §10.3.6); the 1e-12 guards move it by < 1e-11.
    let conv = EntropyConvention::for_task(TaskId::Aligning);
    let h = conditional_entropy(&three_contexts(), &conv).unwrap();
    assert!(close(h, 1.0 / 3.0), "{h}");
}

#[test]
fn sorting_drops_contexts_without_success() {
    // Same data with |B| = 2 and the Drop rule: (1 + 0) / 2 = 1/2 (docs/original-d3il.md §11.6).
    let conv = EntropyConvention {
        n_behaviours: 2,
        ..EntropyConvention::for_task(TaskId::Sorting2)
    };
    assert_eq!(conv.empty_contexts, EmptyContexts::Drop);
    let h = conditional_entropy(&three_contexts(), &conv).unwrap();
    assert!(close(h, 0.5), "{h}");
}

#[test]
fn pushing_unlabeled_successes_are_dropped_but_count_as_success() {
    // c0: successes with modes 0, 3, -1(None), -1(None) → p = (1/2, 1/2) → H = ln2/ln4 = 0.5
    // c1: two successes both None → no labelled success → 0, still counted.
    // Conditional = (0.5 + 0) / 2 = 0.25; success rate = 6/8.
    let v = [
        o(0, true, Some("0")),
        o(0, true, Some("3")),
        o(0, true, None),
        o(0, true, None),
        o(1, true, None),
        o(1, true, None),
        o(1, false, Some("1")),
        o(1, false, Some("2")),
    ];
    let conv = EntropyConvention::for_task(TaskId::Pushing);
    assert!(close(conditional_entropy(&v, &conv).unwrap(), 0.25));
    assert_eq!(success_rate(&v), 0.75);
    // Marginal: labelled successes 0, 3 → ln2/ln4 = 0.5.
    assert!(close(behaviour_entropy(&v, 4).unwrap(), 0.5));
}

#[test]
fn marginal_and_conditional_differ_when_each_context_is_pure() {
    // c0 always mode 0, c1 always mode 1: every H_c = 0, but pooled p = (1/2, 1/2) → 1.
    let v = [
        o(0, true, Some("0")),
        o(0, true, Some("0")),
        o(1, true, Some("1")),
        o(1, true, Some("1")),
    ];
    let conv = EntropyConvention::for_task(TaskId::Aligning);
    assert!(conditional_entropy(&v, &conv).unwrap().abs() < 1e-9);
    assert!(close(behaviour_entropy(&v, 2).unwrap(), 1.0));
}

#[test]
fn reference_guard_matches_reference_arithmetic() {
    // One context, N = 4, modes 0, 0, 0, 1 (all successful), log 2, computed the
    // way aligning_sim.py does: p = (k/N) / (Σk/N + 1e-12); -Σ p ln(p + 1e-12) / ln 2.
    let v = [
        o(0, true, Some("0")),
        o(0, true, Some("0")),
        o(0, true, Some("0")),
        o(0, true, Some("1")),
    ];
    let conv = EntropyConvention::for_task(TaskId::Aligning);
    let p0: f64 = 0.75 / (1.0 + 1e-12);
    let p1: f64 = 0.25 / (1.0 + 1e-12);
    let expected = -(p0 * (p0 + 1e-12).ln() + p1 * (p1 + 1e-12).ln()) / 2f64.ln();
    assert_eq!(conditional_entropy(&v, &conv).unwrap(), expected);
    // ≈ 0.811278 = H(0.75, 0.25) in bits.
    assert!((expected - 0.811278).abs() < 1e-6);
}

#[test]
fn per_context_breakdown() {
    let conv = EntropyConvention::for_task(TaskId::Aligning);
    let pc = per_context(&three_contexts(), &conv).unwrap();
    assert_eq!(pc.len(), 3);
    assert_eq!(pc[0].context_index, 0);
    assert_eq!(pc[0].success_rate, 1.0);
    assert!(close(pc[0].conditional_entropy, 1.0));
    assert_eq!(
        pc[0].behaviours,
        vec![("0".to_string(), 2), ("1".to_string(), 2)]
    );
    assert_eq!(pc[1].success_rate, 0.75);
    assert_eq!(pc[1].behaviours, vec![("0".to_string(), 3)]);
    assert_eq!(pc[2].success_rate, 0.0);
    assert_eq!(pc[2].conditional_entropy, 0.0);
    assert!(pc[2].behaviours.is_empty());
}

#[test]
fn stacking_levels_and_rates() {
    // Context 0: "gbr" full stack; "gb" (2 registered, no stack); "r" (1); "" (none).
    // Context 1: "rgb" full stack; "rg" (2, no stack).
    // Stacking-1 rate: 5/6; Stacking-2: 4/6; Stacking-3: 2/6.
    let v = [
        o(0, true, Some("gbr")),
        o(0, false, Some("gb")),
        o(0, false, Some("r")),
        o(0, false, None),
        o(1, true, Some("rgb")),
        o(1, false, Some("rg")),
    ];
    let ev = evaluate(TaskId::Stacking, &v, 1.5, &Bootstrap::default()).unwrap();
    let s = ev.metrics.stacking.unwrap();
    assert!(close(s[0], 5.0 / 6.0) && close(s[1], 4.0 / 6.0) && close(s[2], 2.0 / 6.0));
    assert!(close(ev.metrics.success_rate.value, 2.0 / 6.0));
    let lv = ev.metrics.stacking_levels.unwrap();
    // Level 1, log 3: c0 first letters g, g, r → p=(2/3,1/3) → H = 0.9183 bits / log2(3)
    // = 0.579380; c1: r, r → 0. Mean over both (both have successes) = 0.289690.
    let h1 = -(2.0 / 3.0 * (2.0f64 / 3.0).ln() + 1.0 / 3.0 * (1.0f64 / 3.0).ln()) / 3f64.ln();
    assert!((lv[0].conditional_entropy.value - h1 / 2.0).abs() < 1e-9);
    // Level 2, log 6: c0 gb, gb → 0; c1 rg, rg → 0.
    assert!(lv[1].conditional_entropy.value.abs() < 1e-9);
    // Level 3, log 6: c0 gbr → 0; c1 rgb → 0; marginal pooled (gbr, rgb) = ln2/ln6.
    assert!(lv[2].conditional_entropy.value.abs() < 1e-9);
    assert!(close(
        ev.metrics.behaviour_entropy.value,
        2f64.ln() / 6f64.ln()
    ));
    assert_eq!(ev.metrics.inference_ms, 1.5);
}

/// −Σ p ln p / ln base over counts.
fn h(counts: &[f64], base: f64) -> f64 {
    let n: f64 = counts.iter().sum();
    -counts.iter().map(|c| c / n * (c / n).ln()).sum::<f64>() / base.ln()
}

#[test]
fn stacking_levels_each_have_their_own_success_and_entropies() {
    // Context 0: full stacks gbr, rgb; two registered gb, bg; one r; none.
    // Context 1: full stacks rbg, rbg; two registered gr; one b.
    let v = [
        o(0, true, Some("gbr")),
        o(0, true, Some("rgb")),
        o(0, false, Some("gb")),
        o(0, false, Some("bg")),
        o(0, false, Some("r")),
        o(0, false, None),
        o(1, true, Some("rbg")),
        o(1, true, Some("rbg")),
        o(1, false, Some("gr")),
        o(1, false, Some("b")),
    ];
    let ev = evaluate(TaskId::Stacking, &v, 0.0, &Bootstrap::default()).unwrap();
    let lv = ev.metrics.stacking_levels.unwrap();

    // Stacking-1 (>= 1 registered, first letter, log 3): 9 of 10.
    // c0: g, r, g, b, r → (2, 2, 1); c1: r, r, g, b → (2, 1, 1); pooled r 4, g 3, b 2.
    assert!(close(lv[0].success_rate.value, 0.9));
    let c1 = (h(&[2.0, 2.0, 1.0], 3.0) + h(&[2.0, 1.0, 1.0], 3.0)) / 2.0;
    assert!(close(lv[0].conditional_entropy.value, c1), "{lv:?}");
    assert!(close(
        lv[0].behaviour_entropy.value,
        h(&[4.0, 3.0, 2.0], 3.0)
    ));

    // Stacking-2 (>= 2 registered, first two letters, log 6): 7 of 10.
    // c0: gb, rg, gb, bg → (2, 1, 1); c1: rb, rb, gr → (2, 1); pooled gb 2, rg 1, bg 1, rb 2, gr 1.
    assert!(close(lv[1].success_rate.value, 0.7));
    let c2 = (h(&[2.0, 1.0, 1.0], 6.0) + h(&[2.0, 1.0], 6.0)) / 2.0;
    assert!(close(lv[1].conditional_entropy.value, c2));
    assert!(close(
        lv[1].behaviour_entropy.value,
        h(&[2.0, 1.0, 1.0, 2.0, 1.0], 6.0)
    ));

    // Stacking-3 (full stack, permutation, log 6): 4 of 10.
    // c0: gbr, rgb → ln 2 / ln 6; c1: rbg, rbg → 0; pooled gbr 1, rgb 1, rbg 2.
    assert!(close(lv[2].success_rate.value, 0.4));
    assert!(close(
        lv[2].conditional_entropy.value,
        h(&[1.0, 1.0], 6.0) / 2.0
    ));
    assert!(close(
        lv[2].behaviour_entropy.value,
        h(&[1.0, 1.0, 2.0], 6.0)
    ));

    // All three differ, and the top-level metrics are Stacking-3's.
    assert!(lv[0].conditional_entropy.value > lv[1].conditional_entropy.value);
    assert!(lv[1].conditional_entropy.value > lv[2].conditional_entropy.value);
    assert_eq!(ev.metrics.success_rate, lv[2].success_rate);
    assert_eq!(ev.metrics.conditional_entropy, lv[2].conditional_entropy);
    assert_eq!(ev.metrics.behaviour_entropy, lv[2].behaviour_entropy);
    assert_eq!(ev.metrics.stacking, Some([0.9, 0.7, 0.4]));
    // Bootstrap intervals are per level too.
    for l in &lv {
        let e = l.conditional_entropy;
        assert!(e.ci_low <= e.value && e.value <= e.ci_high, "{e:?}");
    }
}

#[test]
fn stacking_rejects_bad_labels() {
    let v = [o(3, true, Some("rrg"))];
    let e = evaluate(TaskId::Stacking, &v, 0.0, &Bootstrap::default()).unwrap_err();
    assert!(
        e.to_string().contains("`rrg`") && e.to_string().contains("context 3"),
        "{e}"
    );
    let v = [o(0, true, Some("rgbx"))];
    assert!(stacking_levels(&v).is_err());
}

#[test]
fn seed_aggregation_uses_sample_std() {
    // Five seeds at 1, one at 0: mean 5/6, sample std sqrt((5·(1/6)² + (5/6)²)/5)
    // = sqrt(1/6) = 0.408248 — the paper's BC-GPT Avoiding cell (0.833 ± 0.408).
    let s = aggregate_seeds(&[1.0, 1.0, 1.0, 1.0, 1.0, 0.0]).unwrap();
    assert!(close(s.mean, 5.0 / 6.0));
    assert!(close(s.std, (1.0f64 / 6.0).sqrt()));
    assert_eq!(aggregate_seeds(&[0.4]).unwrap().std, 0.0);
    assert_eq!(aggregate_seeds(&[]).unwrap_err(), MetricsError::NoSeeds);
}

#[test]
fn bootstrap_is_seeded_and_brackets_the_estimate() {
    // 10 contexts, context c has c successes out of 9 rollouts.
    let mut v = vec![];
    for c in 0..10 {
        for r in 0..9 {
            v.push(o(c, r < c, Some(if r % 2 == 0 { "0" } else { "1" })));
        }
    }
    let cfg = Bootstrap {
        resamples: 500,
        confidence: 0.9,
        seed: 7,
    };
    let a = bootstrap(&v, &cfg, Statistic::SuccessRate).unwrap();
    let b = bootstrap(&v, &cfg, Statistic::SuccessRate).unwrap();
    assert_eq!(a, b);
    assert!(close(a.value, 45.0 / 90.0));
    assert!(a.ci_low < a.value && a.value < a.ci_high, "{a:?}");
    // The spread of per-context rates (0..1) gives a wide interval, inside [0, 1].
    assert!(a.ci_low > 0.2 && a.ci_high < 0.8, "{a:?}");
    // 10 states: Korn-Graubard, which draws nothing at random.
    assert_eq!(a.method, Some(d3il_protocol::IntervalMethod::KornGraubard));
    let c = bootstrap(&v, &Bootstrap { seed: 8, ..cfg }, Statistic::SuccessRate).unwrap();
    assert_eq!(a, c);
    // Everything succeeded on 5 states: Clopper-Pearson counting each state
    // once, [(α/2)^(1/5), 1], never width 0.
    let all: Vec<Outcome> = (0..20).map(|i| o(i % 5, true, Some("0"))).collect();
    let e = bootstrap(&all, &cfg, Statistic::SuccessRate).unwrap();
    assert_eq!((e.value, e.ci_high), (1.0, 1.0));
    assert!(close(e.ci_low, 0.05f64.powf(0.2)), "{e:?}");
    // On 4 states there is none, and the estimate says why.
    let four: Vec<Outcome> = (0..20).map(|i| o(i % 4, true, Some("0"))).collect();
    let e = bootstrap(&four, &cfg, Statistic::SuccessRate).unwrap();
    assert_eq!(e.interval(), None);
    assert_eq!(
        e.no_interval,
        Some(d3il_protocol::NoInterval::TooFewStates { states: 4, min: 5 })
    );
    assert_eq!(
        bootstrap(
            &all,
            &Bootstrap {
                confidence: 1.5,
                ..cfg
            },
            Statistic::SuccessRate
        )
        .unwrap_err(),
        MetricsError::BadConfidence(1.5)
    );
}

#[test]
fn bootstrap_over_rollouts_for_single_start() {
    // Avoiding: 480 rollouts of context 0, half succeed → CI around 0.5 with non-zero width.
    let v: Vec<Outcome> = (0..480).map(|i| o(0, i % 2 == 0, Some("37"))).collect();
    let ev = evaluate(TaskId::Avoiding, &v, 0.0, &Bootstrap::default()).unwrap();
    let s = ev.metrics.success_rate;
    assert_eq!(s.value, 0.5);
    assert!(
        s.ci_low < 0.48 && s.ci_high > 0.52 && s.ci_low > 0.4 && s.ci_high < 0.6,
        "{s:?}"
    );
    // One fixed start: the rollouts are trials of the rate itself.
    assert_eq!(
        s.method,
        Some(d3il_protocol::IntervalMethod::ClopperPearsonRollouts)
    );
    let (lo, hi) = intervals::clopper_pearson(240.0, 480.0, 0.05);
    assert_eq!((s.ci_low, s.ci_high), (lo, hi));
    assert_eq!(ev.per_context.len(), 1);
    assert!(ev.metrics.stacking.is_none());
}

#[test]
fn evaluate_rejects_empty_input() {
    assert_eq!(
        evaluate(TaskId::Aligning, &[], 0.0, &Bootstrap::default()).unwrap_err(),
        MetricsError::NoOutcomes
    );
}

#[test]
fn a_single_behaviour_has_entropy_plus_zero() {
    let v = [o(0, true, Some("138")), o(0, true, Some("138"))];
    let h = behaviour_entropy(&v, 24).unwrap();
    assert_eq!(h, 0.0);
    assert!(h.is_sign_positive(), "printed as -0.000 otherwise");
}

#[test]
fn a_deterministic_policys_conditional_entropy_is_exactly_zero() {
    // Pushing-like: every state's two successes share one behaviour. The
    // reference's 1e-12 guards left about 5e-17 here (item 5).
    let v: Vec<Outcome> = (0..12).map(|i| o(i / 2, true, Some("1"))).collect();
    let conv = EntropyConvention::for_task(TaskId::Pushing);
    assert_eq!(conditional_entropy(&v, &conv).unwrap(), 0.0);
    let ev = evaluate(TaskId::Pushing, &v, 0.0, &Bootstrap::default()).unwrap();
    let c = ev.metrics.conditional_entropy;
    assert_eq!((c.value, c.ci_low, c.ci_high), (0.0, 0.0, 0.0), "{c:?}");
    assert!(ev.per_context.iter().all(|p| p.conditional_entropy == 0.0));
    // A real mixture is untouched: one of each of two behaviours → ln 2 / ln |B|.
    let mixed = [o(0, true, Some("0")), o(0, true, Some("1"))];
    let want = 2f64.ln() / (conv.n_behaviours as f64).ln();
    assert!((conditional_entropy(&mixed, &conv).unwrap() - want).abs() < 1e-9);
}
