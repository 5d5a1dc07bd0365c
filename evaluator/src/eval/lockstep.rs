//! The lockstep loop's phases, each a method of [`Lockstep`] so that it can
//! be named, read and tested alone: **gather** the observation windows of
//! the live rollouts that need actions (one batch per window length),
//! **infer** ([`infer`]: one batched policy call, timed and checked),
//! **scatter** the action chunks into the rollouts' queues, **step** every
//! live rollout in parallel, **record** the finished ones and start pending
//! rollouts in their slots. [`super::run_rollouts`] strings them together.

use super::{
    observed, push_images, step_slot, write_prev_actions, EvalError, EvalOptions, Slot, Timing,
};
use crate::perturb::Active;
use crate::tasks::LoadedTask;
use d3il_policy::{validate_actions, ActionChunks, HistoryBuffer, Policy, PolicyShape, Query};
use d3il_protocol::{Ending, ObsType, RolloutRecord, StateOutcome, TaskId};
use rayon::prelude::*;
use serde_json::Value;
use std::collections::VecDeque;
use std::ops::Range;
use std::time::Instant;

/// Which rollouts an evaluation (or a shard of it) runs.
pub(super) struct Plan {
    /// Every initial state of the set, in order (indexed by global context).
    pub contexts: Vec<Value>,
    /// The initial states this run covers.
    pub ctx_range: Range<usize>,
    /// The same states in the order they are started and reported: the
    /// evaluation's random order ([`d3il_metrics::order::state_order`]).
    pub order: Vec<usize>,
    /// Rollouts per initial state in the protocol.
    pub per_ctx: usize,
    /// Rollouts simulated per initial state (1 for a deterministic policy
    /// whose rollouts of one state are one computation).
    pub sim_per_ctx: usize,
}

impl Plan {
    /// Rollouts recorded.
    pub fn total(&self) -> usize {
        self.ctx_range.len() * self.per_ctx
    }
    /// Rollouts simulated.
    pub fn sim_total(&self) -> usize {
        self.ctx_range.len() * self.sim_per_ctx
    }
}

/// The live state of the lockstep loop: one slot per rollout simulated at
/// once, the records so far and the buffers of the next batched query.
pub(super) struct Lockstep<'a> {
    task: &'a LoadedTask,
    opts: &'a EvalOptions,
    plan: Plan,
    shape: PolicyShape,
    record_paths: bool,
    prev_cap: usize,
    pub slots: Vec<Slot>,
    /// The next rollout (in simulation order) to start.
    next: usize,
    records: Vec<Option<RolloutRecord>>,
    keys: Vec<Option<Option<String>>>,
    /// Rollouts recorded so far (copies of once-simulated ones included).
    pub done: usize,
    /// Initial states reported complete so far (a prefix of `plan.order`).
    reported: usize,
    /// Set by [`Lockstep::stop_starting`].
    stopped: bool,
    // The query buffers, reused from call to call.
    ids: Vec<u64>,
    steps: Vec<u64>,
    obs: Vec<f32>,
    images: Vec<f32>,
    prev: Vec<f32>,
}

impl<'a> Lockstep<'a> {
    /// `live` slots (at least one), each with its own environment.
    pub fn new(
        task: &'a LoadedTask,
        policy: &dyn Policy,
        opts: &'a EvalOptions,
        plan: Plan,
        live: usize,
        perturb: Option<&std::sync::Arc<Active>>,
    ) -> Result<Self, EvalError> {
        let shape = policy.shape();
        let spec = task.spec();
        let image = task.obs_type == ObsType::Image;
        let window_mode = policy.window();
        let prev_cap = if policy.takes_prev_actions() {
            shape.history - 1
        } else {
            0
        };
        let mut slots = Vec::with_capacity(live);
        for _ in 0..live {
            slots.push(Slot {
                env: task.env()?,
                rollout: None,
                history: HistoryBuffer::with_mode(shape.history, spec.obs_dim, window_mode),
                images: image.then(|| {
                    HistoryBuffer::with_mode(shape.history, crate::camera::OBS_LEN, window_mode)
                }),
                queue: VecDeque::new(),
                executed: VecDeque::new(),
                prev_cap,
                path: Vec::new(),
                step_cpu_s: 0.0,
                failure: None,
                trace: None,
                perturb: perturb.cloned(),
                in_flight: VecDeque::new(),
                seed: opts.seed,
            });
        }
        let total = plan.total();
        Ok(Lockstep {
            task,
            opts,
            shape,
            record_paths: task.def.id() == TaskId::Avoiding,
            prev_cap,
            slots,
            next: 0,
            records: vec![None; total],
            keys: vec![None; total],
            done: 0,
            reported: 0,
            stopped: false,
            plan,
            ids: Vec::new(),
            steps: Vec::new(),
            obs: Vec::new(),
            images: Vec::new(),
            prev: Vec::new(),
        })
    }

    /// Rollouts recorded when the loop is done.
    pub fn total(&self) -> usize {
        self.plan.total()
    }

    /// Whether a rollout is still running.
    pub fn live(&self) -> bool {
        self.slots.iter().any(|s| s.rollout.is_some())
    }

    /// Starts the next pending rollout in slot `i` (or leaves it empty when
    /// none is left); returns the rollout's id.
    fn start(&mut self, i: usize) -> Result<Option<u64>, EvalError> {
        let plan = &self.plan;
        let slot = &mut self.slots[i];
        if self.stopped || self.next >= plan.sim_total() {
            slot.rollout = None;
            return Ok(None);
        }
        let (ctx, r) = (
            plan.order[self.next / plan.sim_per_ctx],
            self.next % plan.sim_per_ctx,
        );
        // Rollout ids are global (context * per_ctx + index): a shard's
        // rollouts get the ids, hence the policy noise, they have in the
        // whole evaluation.
        let id = ctx * plan.per_ctx + r;
        self.next += 1;
        slot.env.reset(&plan.contexts[ctx])?;
        slot.history.reset();
        if let Some(images) = slot.images.as_mut() {
            // A reused slot still holds its previous rollout's frames: left
            // there, they filled the new episode's first window instead of
            // its own first frame (results then depended on which slot and
            // in which order rollouts ran).
            images.reset();
        }
        slot.history.push(&observed(slot, id))?;
        push_images(slot)?;
        slot.queue.clear();
        slot.in_flight.clear();
        slot.executed.clear();
        slot.path.clear();
        slot.failure = None;
        slot.trace = Some(crate::trace::begin(self.task, &slot.env));
        if self.record_paths {
            let p = slot.env.sim.tcp_pos();
            slot.path.push([p[0] as f32, p[1] as f32]);
        }
        slot.rollout = Some((id, ctx, r));
        Ok(Some(id as u64))
    }

    /// Starts a rollout in every slot; returns their ids.
    pub fn start_all(&mut self) -> Result<Vec<u64>, EvalError> {
        let mut ids = Vec::new();
        for i in 0..self.slots.len() {
            ids.extend(self.start(i)?);
        }
        Ok(ids)
    }

    /// The window lengths of the live rollouts whose action queue is empty,
    /// ascending: one batched query each (windows grow at episode start).
    pub fn windows(&self) -> Vec<usize> {
        let mut windows: Vec<usize> = self
            .slots
            .iter()
            .filter(|s| s.rollout.is_some() && s.queue.is_empty())
            .map(|s| s.history.len())
            .collect();
        windows.sort_unstable();
        windows.dedup();
        windows
    }

    /// **Gather**: the observation windows (and images, and previous
    /// actions) of every live rollout with an empty queue and a window of
    /// length `w`, into the query buffers; returns their slots, in row order.
    pub fn gather(&mut self, w: usize) -> Result<Vec<usize>, EvalError> {
        self.ids.clear();
        self.steps.clear();
        self.obs.clear();
        self.images.clear();
        self.prev.clear();
        let mut rows = Vec::new();
        for (i, s) in self.slots.iter().enumerate() {
            if let Some((id, ..)) = s.rollout {
                if s.queue.is_empty() && s.history.len() == w {
                    self.ids.push(id as u64);
                    self.steps.push(s.env.steps() as u64);
                    s.history.write_window(&mut self.obs)?;
                    if let Some(h) = &s.images {
                        h.write_window(&mut self.images)?;
                    }
                    if self.prev_cap > 0 {
                        write_prev_actions(s, w - 1, self.shape.act_dim, &mut self.prev);
                    }
                    rows.push(i);
                }
            }
        }
        Ok(rows)
    }

    /// The batched query of the last [`Lockstep::gather`] of windows of `w`.
    pub fn query(&self, w: usize) -> Query<'_> {
        let mut query = Query::new(&self.ids, &self.steps, &self.obs);
        query.window = Some(w);
        if self.task.obs_type == ObsType::Image {
            query.images = Some(&self.images);
        }
        if self.prev_cap > 0 {
            query.prev_actions = Some(&self.prev);
        }
        query
    }

    /// **Scatter**: row `k` of `chunks` goes to slot `rows[k]`, whose queue
    /// gets the chunk's first `execute` actions.
    pub fn scatter(&mut self, rows: &[usize], chunks: &ActionChunks) {
        let n = self.shape.execute.min(self.shape.horizon);
        for (row, &i) in rows.iter().enumerate() {
            for h in 0..n {
                self.slots[i]
                    .queue
                    .push_back(chunks.action(row, h).to_vec());
            }
        }
    }

    /// **Step**: every live rollout executes its next action, in parallel.
    pub fn step(&mut self, timing: &mut Timing) -> Result<(), EvalError> {
        let (record_paths, every_frame) = (self.record_paths, self.opts.render_every_frame);
        let ts = Instant::now();
        let results: Vec<Result<bool, EvalError>> = self
            .slots
            .par_iter_mut()
            .filter(|s| s.rollout.is_some())
            .map(|s| {
                let started = Instant::now();
                let r = step_slot(s, record_paths, every_frame);
                s.step_cpu_s += started.elapsed().as_secs_f64();
                r
            })
            .collect();
        timing.physics_s += ts.elapsed().as_secs_f64();
        for r in results {
            r?;
        }
        Ok(())
    }

    /// **Record**: each finished rollout (done, unstable or at the step cap)
    /// becomes its record (and, simulated once for its initial state, the
    /// records of the state's other rollout indices), and its slot starts
    /// the next pending rollout; returns the ids started.
    pub fn record(&mut self) -> Result<Vec<u64>, EvalError> {
        let mut new_ids = Vec::new();
        for i in 0..self.slots.len() {
            if self.retire(i) {
                new_ids.extend(self.start(i)?);
            }
        }
        Ok(new_ids)
    }

    /// Records slot `i`'s rollout if it has ended; whether it had.
    fn retire(&mut self, i: usize) -> bool {
        let (task, spec) = (self.task, self.task.spec());
        let (per_ctx, sim_per_ctx) = (self.plan.per_ctx, self.plan.sim_per_ctx);
        let first_id = self.plan.ctx_range.start * per_ctx;
        let slot = &mut self.slots[i];
        let Some((id, ctx, r)) = slot.rollout else {
            return false;
        };
        let failure = slot.failure.take();
        let capped = self.opts.step_cap.is_some_and(|c| slot.env.steps() >= c);
        if !slot.env.is_done() && failure.is_none() && !capped {
            return false;
        }
        let unstable = failure.is_some();
        // An unstable rollout is a failure at every level, with no behaviour.
        let success = !unstable && slot.env.success();
        let behaviour = if unstable {
            Value::Null
        } else {
            slot.env.behaviour()
        };
        let key = if unstable {
            None
        } else if task.def.id() == TaskId::Stacking {
            // Stacking's levels need the registration order of every rollout.
            behaviour.as_str().map(str::to_string)
        } else {
            slot.env.behaviour_key()
        };
        let steps = slot.env.steps();
        let done = slot.env.is_done();
        let record = RolloutRecord {
            context_index: ctx,
            rollout_index: r,
            success,
            behaviour,
            steps,
            path: self.record_paths.then(|| std::mem::take(&mut slot.path)),
            failure,
            ending: Some(Ending::classify(
                unstable,
                done,
                success,
                steps,
                spec.max_steps,
            )),
            trace: slot
                .trace
                .take()
                .map(|t| Box::new(crate::trace::finish(t, &slot.env))),
        };
        // Simulated once for the whole initial state: the same record also
        // under the state's other rollout indices, which share its trace
        // (EvalResult::trace_of).
        let copies = per_ctx / sim_per_ctx;
        let i = id - first_id;
        for k in 1..copies {
            self.keys[i + k] = Some(key.clone());
            self.records[i + k] = Some(RolloutRecord {
                rollout_index: r + k,
                trace: None,
                ..record.clone()
            });
        }
        self.keys[i] = Some(key);
        self.records[i] = Some(record);
        self.done += copies;
        true
    }

    /// Starts no further rollout: the live ones run to their end (a race
    /// that has decided, [`super::race`]).
    pub fn stop_starting(&mut self) {
        self.stopped = true;
    }

    /// Rollouts started (simulated, or being simulated) so far.
    pub fn started(&self) -> usize {
        self.next
    }

    /// The initial states complete since the last call, in the plan's
    /// order: a state is returned once all its rollouts are recorded and
    /// every state before it in the order has been returned.
    pub fn newly_complete(&mut self) -> Vec<StateOutcome> {
        let per_ctx = self.plan.per_ctx;
        let first_id = self.plan.ctx_range.start * per_ctx;
        let mut out = Vec::new();
        while let Some(&ctx) = self.plan.order.get(self.reported) {
            let at = ctx * per_ctx - first_id;
            let recs = &self.records[at..at + per_ctx];
            if recs.iter().any(Option::is_none) {
                break;
            }
            out.push(StateOutcome {
                position: self.reported,
                context_index: ctx,
                successes: recs.iter().flatten().map(|r| r.success).collect(),
            });
            self.reported += 1;
        }
        out
    }

    /// One turn of the loop: every live rollout that needs actions gets
    /// them (gather, infer, scatter: one batched call per window length),
    /// all step, finished ones are recorded and pending ones start.
    pub fn advance(
        &mut self,
        policy: &mut dyn Policy,
        timing: &mut Timing,
    ) -> Result<(), EvalError> {
        let shape = self.shape;
        for w in self.windows() {
            let rows = self.gather(w)?;
            let chunks = infer(policy, &self.query(w), &shape, timing)?;
            self.scatter(&rows, &chunks);
        }
        self.step(timing)?;
        let started = self.record()?;
        if !started.is_empty() {
            policy.reset(&started)?;
        }
        Ok(())
    }

    /// The records and behaviour keys in rollout order, and the slots (for
    /// their timings).
    pub fn finish(self) -> (Vec<RolloutRecord>, Vec<Option<String>>, Vec<Slot>) {
        let keys = self.keys.into_iter().flatten().collect();
        let records = self.records.into_iter().flatten().collect();
        (records, keys, self.slots)
    }
}

/// **Infer**: one batched policy call, timed, its actions checked.
pub(super) fn infer(
    policy: &mut dyn Policy,
    query: &Query<'_>,
    shape: &PolicyShape,
    timing: &mut Timing,
) -> Result<ActionChunks, EvalError> {
    let tp = Instant::now();
    let chunks = policy.infer(query)?;
    timing.policy_s += tp.elapsed().as_secs_f64();
    timing.policy_calls += 1;
    validate_actions(query, shape, &chunks)?;
    Ok(chunks)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scripted::ScriptedPolicy;

    /// The phases one at a time on three Aligning states, two slots, the
    /// scripted expert simulated once per state (two rollouts recorded each).
    #[test]
    fn the_phases_gather_infer_scatter_step_and_record() {
        let task = LoadedTask::load(TaskId::Aligning).unwrap();
        let mut policy = ScriptedPolicy::from_name("aligning:inside", task.spec()).unwrap();
        let shape = policy.shape();
        let opts = EvalOptions::default();
        let set = task.def.context_set().unwrap();
        let plan = Plan {
            contexts: (0..3).map(|i| set.get(i).unwrap().clone()).collect(),
            ctx_range: 0..3,
            order: vec![0, 1, 2],
            per_ctx: 2,
            sim_per_ctx: 1,
        };
        let mut ls = Lockstep::new(&task, &policy, &opts, plan, 2, None).unwrap();
        // Global ids: initial state × rollouts per state + index.
        let started = ls.start_all().unwrap();
        assert_eq!(started, vec![0, 2]);
        policy.reset(&started).unwrap();

        assert_eq!(ls.windows(), vec![1], "both need actions, window 1");
        let rows = ls.gather(1).unwrap();
        assert_eq!(rows, vec![0, 1]);
        let query = ls.query(1);
        assert_eq!((query.batch(), query.rollout_ids), (2, &[0u64, 2][..]));
        let mut timing = Timing::default();
        let chunks = infer(&mut policy, &ls.query(1), &shape, &mut timing).unwrap();
        assert_eq!(timing.policy_calls, 1);
        ls.scatter(&rows, &chunks);
        assert!(ls.slots.iter().all(|s| s.queue.len() == 1));
        assert!(ls.windows().is_empty(), "nobody needs actions now");

        ls.step(&mut timing).unwrap();
        assert!(ls
            .slots
            .iter()
            .all(|s| s.env.steps() == 1 && s.queue.is_empty()));
        assert!(
            ls.record().unwrap().is_empty(),
            "nothing ended after one step"
        );
        assert_eq!(ls.done, 0);

        let mut all_started = started;
        while ls.live() {
            for w in ls.windows() {
                let rows = ls.gather(w).unwrap();
                let chunks = infer(&mut policy, &ls.query(w), &shape, &mut timing).unwrap();
                ls.scatter(&rows, &chunks);
            }
            ls.step(&mut timing).unwrap();
            let started = ls.record().unwrap();
            policy.reset(&started).unwrap();
            all_started.extend(started);
        }
        assert_eq!(
            all_started,
            vec![0, 2, 4],
            "the third state starts in a freed slot"
        );
        assert_eq!(ls.done, 6);
        let (records, keys, _) = ls.finish();
        assert_eq!(keys.len(), 6);
        let order: Vec<(usize, usize)> = records
            .iter()
            .map(|r| (r.context_index, r.rollout_index))
            .collect();
        assert_eq!(order, vec![(0, 0), (0, 1), (1, 0), (1, 1), (2, 0), (2, 1)]);
        assert!(records.iter().all(|r| r.ending.is_some()));
        // The copy shares its state's trace; only rollout 0 holds it.
        assert!(records[0].trace.is_some() && records[1].trace.is_none());
        assert_eq!(records[0].steps, records[1].steps);
    }
}
