//! The lockstep evaluation engine (DESIGN.md "Evaluation engine"): all
//! rollouts of an evaluation advance together — gather every live rollout's
//! observation window, one batched policy call, scatter the actions, step all
//! rollouts in parallel (rayon), retire finished ones and start pending ones.
//! Each of those phases is a method of `lockstep::Lockstep`; `run_rollouts`
//! strings them together.

mod lockstep;
pub mod race;
mod run;

pub use run::{AllStates, Coverage, EvalRun, Reporter};

use crate::perturb::Active;
use crate::shard::{EvalPart, Shard};
use crate::tasks::{Env, LoadedTask, TaskError};
use d3il_policy::{HistoryBuffer, Policy, PolicyError};
use d3il_protocol::rollout::TraceBuilder;
use d3il_protocol::Progress;
use d3il_protocol::{
    ErrorKind, FailureReason, ObsType, ProtocolKind, ProtocolManifest, RolloutFailure,
    RolloutRecord,
};
use lockstep::{Lockstep, Plan};
use serde_json::Value;
use std::collections::VecDeque;
use std::time::Instant;

#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    #[error(transparent)]
    Policy(#[from] PolicyError),
    #[error("rollout {rollout} (initial state {context}) at step {step}: {source}")]
    Rollout {
        rollout: usize,
        context: usize,
        step: usize,
        #[source]
        source: TaskError,
    },
    #[error(transparent)]
    Task(#[from] TaskError),
    #[error("metrics: {0}")]
    Metrics(#[from] d3il_metrics::MetricsError),
    #[error("{0}")]
    Setup(String),
}

impl EvalError {
    pub fn kind(&self) -> ErrorKind {
        match self {
            EvalError::Policy(p) => p.kind(),
            EvalError::Rollout {
                source: TaskError::NonFinite { .. } | TaskError::ActionWidth { .. },
                ..
            } => ErrorKind::BadAction,
            EvalError::Setup(_) => ErrorKind::BadJob,
            _ => ErrorKind::Internal,
        }
    }
}

/// How many initial states and rollouts per state a protocol uses.
pub fn protocol_size(task: &LoadedTask, protocol: ProtocolKind, n_set: usize) -> (usize, usize) {
    // The task definition may cap the set (Pushing uses the first 30 of 60).
    let set_len = task.def.n_contexts_paper(n_set);
    task.def.id().protocol_size(protocol, set_len)
}

/// What an evaluation under `opts` runs: the protocol's initial states, and
/// its rollouts per state or [`EvalOptions::rollouts_per_state`] of them.
pub fn run_size(task: &LoadedTask, opts: &EvalOptions, n_set: usize) -> (usize, usize) {
    let (n_ctx, per_ctx) = protocol_size(task, opts.protocol, n_set);
    let per_ctx = opts
        .rollouts_per_state
        .map_or(per_ctx, |n| n.clamp(1, per_ctx));
    (n_ctx, per_ctx)
}

/// Knobs of one evaluation.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    pub protocol: ProtocolKind,
    pub seed: u64,
    /// Maximum rollouts simulated at once (bounds memory; each holds one mjData).
    pub max_live: usize,
    /// Bootstrap resamples for the confidence intervals.
    pub bootstrap_resamples: usize,
    /// Dry runs only: end every rollout after this many env steps
    /// ([`d3il_protocol::Job::dry_run_steps`]).
    pub step_cap: Option<usize>,
    /// Image tasks: render the cameras at every env step, also the frames
    /// the policy will never see (by default those are skipped: the ones
    /// that leave the observation window before the next query when a
    /// policy executes more actions per query than its history holds). The
    /// results are the same either way; this is for checking that.
    pub render_every_frame: bool,
    /// Simulate every rollout even when the policy is deterministic
    /// ([`Policy::deterministic`]). By default the rollouts of one initial
    /// state of a deterministic policy are one computation, simulated once and
    /// recorded for each rollout index: the results are the same bit for bit
    /// (`tests/eval/identical_rollouts.rs`). For checking that, and for benchmarks
    /// of the full protocol.
    pub simulate_every_rollout: bool,
    /// The build identity the manifest records (the evaluator cannot know
    /// its own git commit or fingerprint; the binary tells it).
    pub build: Option<d3il_protocol::BuildIdentity>,
    /// Run `n` rollouts of each initial state instead of the protocol's
    /// (at most the protocol's; rollout ids are numbered over `n` per state,
    /// as a protocol of `n` rollouts would number them). For tests that need
    /// a sample of a paper-protocol evaluation, not its cost (`tests/closed_loop.rs`);
    /// the manifest records the rollouts per state that ran. `None`: the
    /// protocol's.
    pub rollouts_per_state: Option<usize>,
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            protocol: ProtocolKind::Paper,
            seed: 0,
            max_live: 96,
            bootstrap_resamples: 1000,
            step_cap: None,
            render_every_frame: false,
            simulate_every_rollout: false,
            build: None,
            rollouts_per_state: None,
        }
    }
}

/// Identity of the policy for the manifest.
#[derive(Debug, Clone)]
pub struct PolicyInfo {
    pub sha256: String,
    pub obs_type: ObsType,
}

/// Wall-clock split of an evaluation.
#[derive(Debug, Clone, Copy, Default)]
pub struct Timing {
    pub total_s: f64,
    pub policy_s: f64,
    /// Wall time of the parallel stepping phases (physics + controller + task
    /// logic, and camera rendering for image tasks).
    pub physics_s: f64,
    pub policy_calls: usize,
    /// Image tasks: time spent rendering during the stepping phases, summed
    /// over threads (CPU seconds, part of `step_cpu_s`).
    pub render_cpu_s: f64,
    /// Time spent stepping envs, summed over threads (CPU seconds, rendering included).
    pub step_cpu_s: f64,
    /// Image tasks: image observations rendered in env steps (each both
    /// cameras; resets not counted).
    pub frames_rendered: usize,
    /// Rollouts recorded (the protocol's, or the shard's).
    pub rollouts: usize,
    /// Rollouts actually simulated: fewer than recorded when a deterministic
    /// policy's rollouts of one initial state were simulated once.
    pub rollouts_simulated: usize,
}

struct Slot {
    env: Env,
    rollout: Option<(usize, usize, usize)>, // (id, context, index within context)
    history: HistoryBuffer,
    /// Image policies: the last k image observations.
    images: Option<HistoryBuffer>,
    queue: VecDeque<Vec<f32>>,
    /// The last actions executed this episode, newest last (at most
    /// `prev_cap`, for policies that take `prev_actions`).
    executed: VecDeque<Vec<f32>>,
    prev_cap: usize,
    path: Vec<[f32; 2]>,
    /// Seconds spent in [`step_slot`] (benchmarks).
    step_cpu_s: f64,
    /// Set when the simulation became unstable: the rollout ends as a failure.
    failure: Option<RolloutFailure>,
    /// What the rollout did, for replays ([`crate::trace`]).
    trace: Option<TraceBuilder>,
    /// The robustness track's perturbation (None: the standard protocol).
    perturb: Option<std::sync::Arc<Active>>,
    /// Latency: the policy's actions not yet applied, oldest first.
    in_flight: VecDeque<Vec<f32>>,
    /// The evaluation's seed (observation noise).
    seed: u64,
}

/// Runs `policy` on `task` under `opts` and computes the D3IL metrics: of
/// every initial state ([`EvalRun::all`], an [`EvalResult`]) or of one shard
/// ([`EvalRun::shard`], its [`EvalPart`]), perturbed or not.
pub fn evaluate<C: Coverage>(
    task: &LoadedTask,
    policy: &mut dyn Policy,
    info: &PolicyInfo,
    opts: &EvalOptions,
    run: EvalRun<'_, C>,
) -> Result<(C::Output, Timing), EvalError> {
    let t0 = Instant::now();
    let EvalRun {
        states,
        perturbation,
        mut progress,
    } = run;
    let rollouts = match perturbation {
        None => run_rollouts(
            task,
            policy,
            info,
            opts,
            states.shard(),
            None,
            &mut progress,
        )?,
        Some(p) => {
            let (perturbed, active) = activate(task, p)?;
            run_rollouts(
                &perturbed,
                policy,
                info,
                opts,
                states.shard(),
                Some(&active),
                &mut progress,
            )?
        }
    };
    states.finish(rollouts, opts, t0)
}

pub use d3il_metrics::shard::{assemble, inference_ms};

/// The task as `perturbation` simulates it, and the perturbation ready to act.
fn activate(
    task: &LoadedTask,
    perturbation: &d3il_protocol::perturbation::Perturbation,
) -> Result<(LoadedTask, std::sync::Arc<Active>), EvalError> {
    let active =
        Active::new(perturbation, task.def.id()).map_err(|e| EvalError::Setup(e.to_string()))?;
    let perturbed = active
        .task(task)
        .map_err(|e| EvalError::Setup(e.to_string()))?;
    Ok((perturbed, std::sync::Arc::new(active)))
}

/// The rollouts of one evaluation (or of one shard of it), before metrics.
#[doc(hidden)]
pub struct Rollouts {
    manifest: ProtocolManifest,
    /// The initial states this run covered (all of them without a shard).
    contexts: std::ops::Range<usize>,
    rollouts: Vec<RolloutRecord>,
    behaviour_keys: Vec<Option<String>>,
    timing: Timing,
}

impl Rollouts {
    /// The part file of shard `shard` (`d3il merge` joins the parts).
    fn into_part(self, shard: Shard, opts: &EvalOptions) -> (EvalPart, Timing) {
        (
            EvalPart {
                format: crate::shard::PART_FORMAT.into(),
                manifest: self.manifest,
                shard,
                contexts: [self.contexts.start, self.contexts.end],
                rollouts: self.rollouts,
                behaviour_keys: self.behaviour_keys,
                policy_seconds: self.timing.policy_s,
                policy_calls: self.timing.policy_calls,
                bootstrap_resamples: opts.bootstrap_resamples,
            },
            self.timing,
        )
    }
}

/// What an evaluation (or a shard, or one side of a race) runs: the states,
/// their order, how many rollouts of each are simulated, the slots.
struct Prepared {
    set: crate::tasks::ContextSet,
    n_ctx: usize,
    per_ctx: usize,
    ctx_range: std::ops::Range<usize>,
    sim_per_ctx: usize,
    plan: Plan,
    live: usize,
    shape: d3il_policy::PolicyShape,
}

/// Checks `policy` against `task` (observation type, dimensions, a test
/// inference) and plans its rollouts under `opts`.
fn prepare(
    task: &LoadedTask,
    policy: &mut dyn Policy,
    opts: &EvalOptions,
    shard: Option<Shard>,
    perturb: Option<&std::sync::Arc<Active>>,
) -> Result<Prepared, EvalError> {
    let set = task.def.context_set()?;
    let (n_ctx, per_ctx) = run_size(task, opts, set.len());
    let ctx_range = match shard {
        Some(s) => s
            .contexts(n_ctx)
            .map_err(|e| EvalError::Setup(e.to_string()))?,
        None => 0..n_ctx,
    };
    // A deterministic policy's rollouts of one initial state are the same
    // computation (the reset, the physics and each row's actions are
    // functions of their inputs alone): simulate rollout 0 of each state and
    // record it under every rollout index.
    // Observation noise is drawn per rollout: the rollouts of one state
    // differ even for a deterministic policy.
    let noisy = perturb.is_some_and(|p| p.noise.is_some());
    let sim_per_ctx = if policy.deterministic() && !opts.simulate_every_rollout && !noisy {
        1
    } else {
        per_ctx
    };
    let sim_total = ctx_range.len() * sim_per_ctx;
    let shape = policy.shape();
    let spec = task.spec();
    if shape.obs_type != task.obs_type {
        return Err(EvalError::Setup(format!(
            "the policy takes {} observations but the task was loaded for {} observations",
            shape.obs_type, task.obs_type
        )));
    }
    if shape.obs_dim != spec.obs_dim || shape.act_dim != spec.act_dim {
        return Err(EvalError::Setup(format!(
            "policy dimensions obs {} / act {} do not match task {} (obs {}, act {})",
            shape.obs_dim, shape.act_dim, spec.task, spec.obs_dim, spec.act_dim
        )));
    }
    // A graph that cannot run is refused here, with tract's reason, not at rollout 0.
    policy.self_test()?;
    let live = sim_total.min(opts.max_live.max(1));
    let plan = Plan {
        contexts: (0..n_ctx)
            .map(|i| {
                let c = set.get(i).cloned().unwrap_or(Value::Null);
                match perturb {
                    Some(p) => p.context(&c),
                    None => c,
                }
            })
            .collect(),
        ctx_range: ctx_range.clone(),
        // The evaluation's random order of its states: any prefix
        // of what has finished is a fair sample. The records are stored by
        // rollout id, so the result does not depend on it.
        order: d3il_metrics::order::state_order(n_ctx, opts.seed)
            .into_iter()
            .filter(|c| ctx_range.contains(c))
            .collect(),
        per_ctx,
        sim_per_ctx,
    };
    Ok(Prepared {
        set,
        n_ctx,
        per_ctx,
        ctx_range,
        sim_per_ctx,
        plan,
        live,
        shape,
    })
}

fn run_rollouts(
    task: &LoadedTask,
    policy: &mut dyn Policy,
    info: &PolicyInfo,
    opts: &EvalOptions,
    shard: Option<Shard>,
    perturb: Option<&std::sync::Arc<Active>>,
    progress: &mut Reporter,
) -> Result<Rollouts, EvalError> {
    let t0 = Instant::now();
    let mut timing = Timing::default();
    let Prepared {
        set,
        n_ctx,
        per_ctx,
        ctx_range,
        sim_per_ctx,
        plan,
        live,
        shape,
    } = prepare(task, policy, opts, shard, perturb)?;
    let total = ctx_range.len() * per_ctx;
    let sim_total = ctx_range.len() * sim_per_ctx;
    let mut lockstep = Lockstep::new(task, policy, opts, plan, live, perturb)?;
    let started = lockstep.start_all()?;
    policy.reset(&started)?;
    while lockstep.live() {
        lockstep.advance(policy, &mut timing)?;
        progress.report(&Progress {
            rollouts_done: lockstep.done,
            rollouts_total: lockstep.total(),
            states: lockstep.newly_complete(),
            race: None,
        });
    }
    let (rollouts, behaviour_keys, slots) = lockstep.finish();
    let manifest = ProtocolManifest {
        task: task.def.id(),
        task_version: task.def.version().into(),
        obs_type: info.obs_type,
        protocol: opts.protocol,
        robot_look: (task.obs_type == ObsType::Image).then_some(task.look),
        mjcf_sha256: task.mjcf_sha256.clone(),
        initial_states_sha256: set.sha256.clone(),
        initial_states: set.name.clone(),
        mujoco_version: crate::mujoco::version(),
        evaluator_version: env!("CARGO_PKG_VERSION").into(),
        n_contexts: n_ctx,
        rollouts_per_context: per_ctx,
        max_steps: task.spec().max_steps,
        policy_sha256: info.sha256.clone(),
        history: shape.history,
        horizon: shape.horizon,
        execute: shape.execute,
        seed: opts.seed,
        simulated_once: sim_per_ctx < per_ctx,
        build: opts.build.clone(),
        perturbation: perturb.map(|p| p.perturbation.clone()),
    };
    timing.total_s = t0.elapsed().as_secs_f64();
    timing.step_cpu_s = slots.iter().map(|s| s.step_cpu_s).sum();
    timing.render_cpu_s = slots.iter().map(|s| s.env.render_seconds()).sum();
    timing.frames_rendered = slots.iter().map(|s| s.env.frames_rendered()).sum();
    timing.rollouts = total;
    timing.rollouts_simulated = sim_total;
    Ok(Rollouts {
        manifest,
        contexts: ctx_range,
        rollouts,
        behaviour_keys,
        timing,
    })
}

/// One env step of a live slot: the next queued action, then the new
/// observation into the history. Returns whether the rollout is done. A
/// MuJoCo warning (instability, buffer overflow) ends the rollout as a
/// failure (`slot.failure`) instead of failing the evaluation; an invalid
/// action from the policy still fails it.
fn step_slot(s: &mut Slot, record_paths: bool, every_frame: bool) -> Result<bool, EvalError> {
    let (id, ctx, _) = s.rollout.expect("filtered to live slots");
    let issued = s.queue.pop_front().unwrap_or_default();
    // Latency: the environment gets the action issued `latency` steps ago
    // (the hold action before the first arrives); the policy's own memory
    // of its actions (`executed`) keeps what it issued.
    let action = match s.perturb.as_deref() {
        Some(p) if p.latency > 0 || p.late_fraction > 0.0 => {
            s.in_flight.push_back(issued.clone());
            // The action issued `k` steps ago (the hold action before the first).
            let late = |k: usize| match s.in_flight.len().checked_sub(k + 1) {
                Some(i) => s.in_flight[i].clone(),
                None => p.hold.clone(),
            };
            let (action, keep) = if p.late_fraction > 0.0 {
                let (newer, older) = (late(p.latency), late(p.latency + 1));
                let blend = p.command.blend_late(&newer, &older, p.late_fraction);
                (blend, p.latency + 1)
            } else {
                (late(p.latency), p.latency)
            };
            while s.in_flight.len() > keep {
                s.in_flight.pop_front();
            }
            action
        }
        _ => issued.clone(),
    };
    // The frame this step renders is pushed now; the next query comes after
    // the `queue.len()` actions still queued, each pushing one more frame,
    // and reads the k newest: this one only if fewer than k are queued.
    if let Some(images) = &s.images {
        if !every_frame && s.queue.len() >= images.capacity() {
            s.env.skip_next_frame();
        }
    }
    let step = s.env.steps();
    let stepped = s.env.step(&action);
    if let (Ok(_) | Err(TaskError::SimulationWarning { .. }), Some(trace)) =
        (&stepped, s.trace.as_mut())
    {
        crate::trace::record_step(trace, &s.env, &action);
    }
    let out = match stepped {
        Ok(out) => out,
        Err(TaskError::SimulationWarning { step, warnings }) => {
            s.failure = Some(RolloutFailure {
                reason: FailureReason::SimUnstable,
                message: warnings,
                step,
            });
            return Ok(true);
        }
        Err(source) => {
            return Err(EvalError::Rollout {
                rollout: id,
                context: ctx,
                step,
                source,
            })
        }
    };
    if s.prev_cap > 0 {
        if s.executed.len() == s.prev_cap {
            s.executed.pop_front();
        }
        s.executed.push_back(issued);
    }
    s.history.push(&observed(s, id))?;
    push_images(s)?;
    if record_paths {
        let p = s.env.sim.tcp_pos();
        s.path.push([p[0] as f32, p[1] as f32]);
    }
    Ok(out.done)
}

/// The policy's observation of slot `s` (rollout `id`) now: the env's, with
/// the observation noise of a perturbation.
fn observed(s: &Slot, id: usize) -> Vec<f32> {
    let mut obs = s.env.policy_obs();
    if let Some(noise) = s.perturb.as_deref().and_then(|p| p.noise.as_ref()) {
        noise.apply(s.seed, id as u64, s.env.steps() as u64, &mut obs);
    }
    obs
}

/// Appends the last `n` executed actions of the slot (oldest first) to `out`,
/// zeros in front of the episode's first action (padded windows only).
fn write_prev_actions(s: &Slot, n: usize, act_dim: usize, out: &mut Vec<f32>) {
    let have = s.executed.len().min(n);
    out.resize(out.len() + (n - have) * act_dim, 0.0);
    for a in s.executed.iter().skip(s.executed.len() - have) {
        out.extend_from_slice(a);
    }
}

/// Appends the slot's current image observation to its image history.
fn push_images(slot: &mut Slot) -> Result<(), EvalError> {
    if let (Some(h), Some(im)) = (slot.images.as_mut(), slot.env.policy_images()) {
        h.push(im)?;
    }
    Ok(())
}

/// The one sha256 helper of the crate (also used for the context sets).
pub use crate::tasks::contexts::sha256_hex;
