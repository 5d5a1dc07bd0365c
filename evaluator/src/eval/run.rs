//! What one evaluation runs besides its options: which initial states
//! ([`Coverage`]: all of them, or one shard), under which perturbation,
//! reporting progress to whom ([`EvalRun`], [`Reporter`]); the engine in
//! the parent module runs it.

use super::{assemble, inference_ms, EvalError, EvalOptions, Rollouts, Timing};
use crate::shard::{EvalPart, Shard};
use d3il_protocol::{EvalResult, Progress};
use std::time::Instant;

/// Which initial states an evaluation runs, and so what it gives: all of
/// them ([`AllStates`]) give an [`EvalResult`], one shard ([`Shard`]) the
/// [`EvalPart`] that [`crate::shard::merge`] joins with the other shards
/// into the result of all of them.
pub trait Coverage: Copy + sealed::Sealed {
    /// What the evaluation gives.
    type Output;
    /// The shard, if the evaluation runs only one.
    fn shard(self) -> Option<Shard>;
    /// The output of the rollouts `run` ran (started at `t0`).
    #[doc(hidden)]
    fn finish(
        self,
        run: Rollouts,
        opts: &EvalOptions,
        t0: Instant,
    ) -> Result<(Self::Output, Timing), EvalError>;
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for super::AllStates {}
    impl Sealed for super::Shard {}
}

/// Every initial state of the protocol: the evaluation gives its result.
#[derive(Debug, Clone, Copy, Default)]
pub struct AllStates;

impl Coverage for AllStates {
    type Output = EvalResult;
    fn shard(self) -> Option<Shard> {
        None
    }
    fn finish(
        self,
        run: Rollouts,
        opts: &EvalOptions,
        t0: Instant,
    ) -> Result<(EvalResult, Timing), EvalError> {
        let mut timing = run.timing;
        let result = assemble(
            run.manifest,
            run.rollouts,
            &run.behaviour_keys,
            inference_ms(timing.policy_s, timing.policy_calls),
            opts.bootstrap_resamples,
        )?;
        // The total includes the metrics' bootstrap.
        timing.total_s = t0.elapsed().as_secs_f64();
        Ok((result, timing))
    }
}

/// One shard of the protocol (a contiguous block of whole initial states,
/// [`Shard::contexts`]): the evaluation gives the shard's part. Rollouts
/// keep their global indices, so the policy sees the same rollout ids (and
/// noise) as in an unsharded run.
impl Coverage for Shard {
    type Output = EvalPart;
    fn shard(self) -> Option<Shard> {
        Some(self)
    }
    fn finish(
        self,
        run: Rollouts,
        opts: &EvalOptions,
        _t0: Instant,
    ) -> Result<(EvalPart, Timing), EvalError> {
        Ok(run.into_part(self, opts))
    }
}

/// Who hears an evaluation's progress.
#[derive(Default)]
pub enum Reporter<'a> {
    /// Nobody.
    #[default]
    Silent,
    /// Rollouts done and the total, after each lockstep step.
    Counts(&'a mut dyn FnMut(usize, usize)),
    /// The whole [`Progress`]: also the initial states newly finished, in
    /// the evaluation's random order ([`Progress::states`];
    /// docs/sequential.md; with a shard, the order of all states less those
    /// of other shards).
    Progress(&'a mut dyn FnMut(&Progress)),
}

impl Reporter<'_> {
    pub(super) fn report(&mut self, p: &Progress) {
        match self {
            Reporter::Silent => {}
            Reporter::Counts(f) => f(p.rollouts_done, p.rollouts_total),
            Reporter::Progress(f) => f(p),
        }
    }
}

/// What one evaluation runs besides its [`EvalOptions`]: which initial
/// states ([`Coverage`]: all, or one shard), under which perturbation of
/// the robustness track, reporting progress to whom. Built with
/// [`EvalRun::all`] or [`EvalRun::shard`], then [`EvalRun::perturbed`],
/// [`EvalRun::counting`] or [`EvalRun::reporting`].
pub struct EvalRun<'a, C: Coverage = AllStates> {
    pub states: C,
    /// A perturbation of the robustness track ([`crate::perturb`]): the same
    /// initial states (shifted for `start_shift`), seed and rollout ids,
    /// hence the same policy noise, as the plain evaluation that is its
    /// level 0; the manifest records the perturbation. Deterministic
    /// policies are simulated once per initial state as in a plain
    /// evaluation, except under observation noise, which differs from
    /// rollout to rollout.
    pub perturbation: Option<&'a d3il_protocol::perturbation::Perturbation>,
    pub progress: Reporter<'a>,
}

impl<'a> EvalRun<'a> {
    /// Every initial state of the protocol, unperturbed, silently.
    pub fn all() -> Self {
        EvalRun {
            states: AllStates,
            perturbation: None,
            progress: Reporter::Silent,
        }
    }
}

impl<'a> EvalRun<'a, Shard> {
    /// Shard `shard` only, unperturbed, silently (`d3il eval --shard K/N`).
    pub fn shard(shard: Shard) -> Self {
        EvalRun {
            states: shard,
            perturbation: None,
            progress: Reporter::Silent,
        }
    }
}

impl<'a, C: Coverage> EvalRun<'a, C> {
    /// The same run under `perturbation`.
    pub fn perturbed(self, perturbation: &'a d3il_protocol::perturbation::Perturbation) -> Self {
        EvalRun {
            perturbation: Some(perturbation),
            ..self
        }
    }

    /// The same run, reporting `(done, total)` rollouts to `on_progress`.
    pub fn counting(self, on_progress: &'a mut dyn FnMut(usize, usize)) -> Self {
        EvalRun {
            progress: Reporter::Counts(on_progress),
            ..self
        }
    }

    /// The same run, reporting every [`Progress`] to `on_progress`.
    pub fn reporting(self, on_progress: &'a mut dyn FnMut(&Progress)) -> Self {
        EvalRun {
            progress: Reporter::Progress(on_progress),
            ..self
        }
    }
}
