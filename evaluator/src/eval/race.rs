//! A sequential race of two policies: both run on the
//! same initial states in the same random order, with the same seed and
//! rollout ids (hence the same noise seeds), interleaved turn by turn; as a
//! state completes for both, its paired outcomes go to the sequential
//! paired test ([`SequentialComparison`], deciding by the boundary
//! calibrated to the protocol's number of initial states; its e-value and
//! anytime-valid p-value are reported), and the race stops starting
//! rollouts as soon as it decides, or runs the protocol's full size.
//! docs/sequential.md has the rule.

use super::lockstep::Lockstep;
use super::{prepare, EvalError, EvalOptions, PolicyInfo, Timing};
use crate::tasks::LoadedTask;
use d3il_metrics::sequential::{FixedPairedTest, SequentialComparison};
use d3il_policy::Policy;
pub use d3il_protocol::race::{RaceProgress, RaceReport};
use d3il_protocol::StateOutcome;

/// One side of a race: a loaded policy ([`crate::job::load_policy`]).
pub struct Contender<'a> {
    pub policy: &'a mut dyn Policy,
    pub info: &'a PolicyInfo,
}

/// The test's level and margin.
#[derive(Debug, Clone, Copy)]
pub struct RaceOptions {
    /// Two-sided level α of the sequential test, in (0, 1).
    pub alpha: f64,
    /// With a margin δ in (0, 2): also stop with "no difference larger than
    /// δ" when the confidence sequence of rate(A) − rate(B) lies inside
    /// (−δ, δ).
    pub delta: Option<f64>,
}

impl Default for RaceOptions {
    fn default() -> Self {
        RaceOptions {
            alpha: d3il_protocol::race::DEFAULT_ALPHA,
            delta: None,
        }
    }
}

impl RaceOptions {
    /// A clear error for a level or margin out of range.
    pub fn check(&self) -> Result<(), EvalError> {
        d3il_protocol::race::check_race_params(self.alpha, self.delta)
            .map_err(|e| EvalError::Setup(e.message))
    }
}

/// Races `a` against `b` on `task` under `opts` (protocol, seed, and
/// `max_live`: rollouts simulated at once per policy; fewer stop sooner
/// after a decision, more run faster). `on_pair` is called after every
/// state completed for both.
pub fn race(
    task: &LoadedTask,
    a: Contender<'_>,
    b: Contender<'_>,
    opts: &EvalOptions,
    race_opts: &RaceOptions,
    on_pair: &mut dyn FnMut(&RaceProgress),
) -> Result<RaceReport, EvalError> {
    race_opts.check()?;
    let t0 = std::time::Instant::now();
    let pa = prepare(task, a.policy, opts, None, None)?;
    let pb = prepare(task, b.policy, opts, None, None)?;
    let (n_ctx, per_ctx) = (pa.n_ctx, pa.per_ctx);
    // One pair per initial state, its rollout 0: states come in random
    // order, exchangeable; the rollouts of one state are not independent
    // evidence (copies for a deterministic policy, correlated through the
    // state otherwise).
    let mut la = Lockstep::new(task, &*a.policy, opts, pa.plan, pa.live, None)?;
    let mut lb = Lockstep::new(task, &*b.policy, opts, pb.plan, pb.live, None)?;
    let started = la.start_all()?;
    a.policy.reset(&started)?;
    let started = lb.start_all()?;
    b.policy.reset(&started)?;
    let mut timing = Timing::default();
    let (mut done_a, mut done_b) = (Vec::new(), Vec::new());
    // The protocol fixes the horizon: at most one pair per initial state,
    // so the boundary calibrated to n_ctx pairs decides (its exact type-I
    // error over at most n_ctx pairs is <= alpha; the e-value is reported).
    let mut test = SequentialComparison::with_horizon(race_opts.alpha, race_opts.delta, n_ctx);
    let (mut paired, mut wins) = (0usize, (0u64, 0u64));
    let (mut successes_a, mut successes_b) = (0usize, 0usize);
    let mut outcomes = String::new();
    'race: while la.live() || lb.live() {
        if la.live() {
            la.advance(a.policy, &mut timing)?;
            done_a.extend(la.newly_complete());
        }
        if lb.live() {
            lb.advance(b.policy, &mut timing)?;
            done_b.extend(lb.newly_complete());
        }
        while paired < done_a.len().min(done_b.len()) {
            let (sa, sb): (&StateOutcome, &StateOutcome) = (&done_a[paired], &done_b[paired]);
            debug_assert_eq!(sa.context_index, sb.context_index);
            paired += 1;
            successes_a += sa.successes.iter().filter(|s| **s).count();
            successes_b += sb.successes.iter().filter(|s| **s).count();
            let (x, y) = (sa.successes[0], sb.successes[0]);
            wins.0 += (x && !y) as u64;
            wins.1 += (y && !x) as u64;
            test.observe(x, y);
            outcomes.push(d3il_protocol::race::pair_code(x, y));
            let e = test.eprocess();
            on_pair(&RaceProgress {
                states: paired,
                states_total: n_ctx,
                pairs: e.pairs(),
                e_value: e.e_value(),
                p_value: e.p_value(),
                discordant: e.discordant(),
                decision: test.decision().map(|d| d.to_string()),
                a: sa.clone(),
                b: sb.clone(),
            });
            if test.decision().is_some() {
                la.stop_starting();
                lb.stop_starting();
                break 'race;
            }
        }
    }
    let simulated = la.started() + lb.started();
    let e = test.eprocess();
    let rollouts_used = 2 * paired * per_ctx;
    let (p_a, p_b) = (
        wins.0 as f64 / e.pairs().max(1) as f64,
        wins.1 as f64 / e.pairs().max(1) as f64,
    );
    let mut fixed = FixedPairedTest::new(race_opts.alpha);
    let (hi, lo) = if p_a >= p_b { (p_a, p_b) } else { (p_b, p_a) };
    Ok(RaceReport {
        task: task.def.id(),
        protocol: opts.protocol,
        seed: opts.seed,
        alpha: race_opts.alpha,
        delta: race_opts.delta,
        pair: "initial state (its rollout 0)".into(),
        decision: test.decision().map(|d| d.to_string()),
        decided_at: test.decided_at(),
        e_value: e.e_value(),
        p_value: e.p_value(),
        discordant: e.discordant(),
        difference_interval: test.difference_interval(),
        rate_a: successes_a as f64 / (paired * per_ctx).max(1) as f64,
        rate_b: successes_b as f64 / (paired * per_ctx).max(1) as f64,
        pairs_used: e.pairs(),
        pairs_full: n_ctx as u64,
        states_used: paired,
        states_full: n_ctx,
        rollouts_used,
        rollouts_full: 2 * n_ctx * per_ctx,
        rollouts_simulated: simulated,
        fixed_p_value: fixed.p_value(wins.0, wins.1),
        fixed_pairs_for_power_90: fixed.pairs_for_power(hi, lo, 0.9, 100_000),
        seconds: t0.elapsed().as_secs_f64(),
        policy_calls: timing.policy_calls,
        outcomes,
    })
}
