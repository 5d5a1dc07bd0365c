//! Running a batch: inputs built from the query (normalised, noise drawn per
//! row), split across threads with one plan run per thread, rows padded up to
//! the plan's batch by repeating the last row.

use super::admit::Feed;
use super::load::bucket;
use super::{panic_error, OnnxPolicy};
use crate::{PolicyError, Query, IMAGE_LEN, IMAGE_SHAPE};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::panic::{catch_unwind, AssertUnwindSafe};
use tract_onnx::prelude::*;

/// The actions of one group of rows, with the group's index.
type GroupOutput = (usize, Vec<f32>);

/// Fewest rows worth a thread of their own.
const MIN_ROWS_PER_THREAD: usize = 2;

/// Largest intermediate tensor of one plan run a call aims at: groups of
/// rows stay below it (about a quarter of a core's L2 cache here), so a
/// model with wide per-row activations (IBC: 64 samples × 64 units per row)
/// runs in several smaller plan runs per thread, each in cache.
const MAX_GROUP_BYTES: usize = 512 * 1024;

/// Fewest rows a group is cut down to for [`MAX_GROUP_BYTES`] (models whose
/// rows alone exceed the cache, such as image networks, are not cut finer).
const MIN_GROUP_ROWS: usize = 8;

/// Least work (tract's cost estimate: multiply-adds plus other element
/// operations) worth a thread of its own, about 0.1 ms on one core; below
/// it spawning the thread costs more than it saves.
const MIN_WORK_PER_THREAD: u64 = 2_000_000;

impl OnnxPolicy {
    /// Standard normal noise for one row, a pure function of (seed, rollout, step)
    /// so results do not depend on batch composition or chunking.
    fn noise_row(&self, rollout: u64, step: u64, out: &mut Vec<f32>) {
        let mut key = [0u8; 32];
        key[0..8].copy_from_slice(&self.seed.to_le_bytes());
        key[8..16].copy_from_slice(&rollout.to_le_bytes());
        key[16..24].copy_from_slice(&step.to_le_bytes());
        key[24..32].copy_from_slice(b"d3ilnois");
        let mut rng = ChaCha8Rng::from_seed(key);
        let n: usize = self.sig.noise_dims.iter().product();
        out.extend((0..n).map(|_| {
            let v: f32 = StandardNormal.sample(&mut rng);
            v
        }));
    }

    /// All rows of a query, split across threads (or run in groups of a
    /// fixed batch); returns `[B, H, act_dim]` flattened, in row order.
    pub(super) fn run_query(&self, q: &Query<'_>) -> Result<Vec<f32>, PolicyError> {
        let b = q.batch();
        // Small calls stay on one thread: a spawned thread costs more than
        // it saves below MIN_WORK_PER_THREAD.
        let work = (b as u64).saturating_mul(self.model.work_per_row());
        let threads = self
            .threads
            .min(usize::try_from(work / MIN_WORK_PER_THREAD).unwrap_or(usize::MAX))
            .max(1);
        let mut groups: Vec<(std::ops::Range<usize>, usize)> = vec![];
        match self.sig.fixed_batch {
            Some(n) => {
                let mut start = 0;
                while start < b {
                    let end = (start + n).min(b);
                    groups.push((start..end, n));
                    start = end;
                }
            }
            None if b > 0 => {
                let t = threads.min(b.div_ceil(MIN_ROWS_PER_THREAD)).max(1);
                // As many groups per thread as keep a group's largest
                // intermediate tensor within MAX_GROUP_BYTES (cache-sized).
                let cap =
                    (MAX_GROUP_BYTES / self.model.largest_row_bytes().max(1)).max(MIN_GROUP_ROWS);
                let per_thread = b.div_ceil(t).div_ceil(cap);
                let per = b.div_ceil(t * per_thread);
                let mut start = 0;
                while start < b {
                    let end = (start + per).min(b);
                    groups.push((start..end, bucket(end - start)));
                    start = end;
                }
            }
            None => {}
        }
        let per_row = self.shape.horizon * self.shape.act_dim;
        let mut data = Vec::with_capacity(b * per_row);
        if groups.len() <= 1 || threads <= 1 {
            for (rows, n) in groups {
                self.run_rows(q, rows, n, &mut data)?;
            }
            return Ok(data);
        }
        // Groups beyond the thread count run in turn on their thread; the
        // calling thread takes its share too, so a call spawns threads − 1.
        let threads = threads.min(groups.len());
        let share = |t: usize| -> Vec<(usize, (std::ops::Range<usize>, usize))> {
            groups
                .iter()
                .enumerate()
                .filter(|(i, _)| i % threads == t)
                .map(|(i, g)| (i, g.clone()))
                .collect()
        };
        let run_share = |mine: Vec<(usize, (std::ops::Range<usize>, usize))>| {
            let mut outs = vec![];
            for (i, (rows, n)) in mine {
                let mut out = Vec::new();
                self.run_rows(q, rows, n, &mut out)?;
                outs.push((i, out));
            }
            Ok(outs)
        };
        let results: Vec<Result<Vec<GroupOutput>, PolicyError>> = std::thread::scope(|scope| {
            let handles: Vec<_> = (1..threads)
                .map(|t| {
                    let mine = share(t);
                    scope.spawn(move || run_share(mine))
                })
                .collect();
            let own = catch_unwind(AssertUnwindSafe(|| run_share(share(0))));
            std::iter::once(own)
                .chain(handles.into_iter().map(|h| h.join()))
                .map(|r| {
                    r.unwrap_or_else(|p| {
                        let (rollout, step) = (q.rollout_ids[0], q.steps[0]);
                        Err(panic_error(
                            p,
                            format!("in the query of rollout {rollout} at step {step}"),
                            |msg| PolicyError::Inference {
                                rollout,
                                step,
                                message: format!("the ONNX runtime panicked ({msg})"),
                            },
                        ))
                    })
                })
                .collect()
        });
        let mut parts: Vec<GroupOutput> = vec![];
        for r in results {
            parts.extend(r?);
        }
        parts.sort_by_key(|(i, _)| *i);
        for (_, p) in parts {
            data.extend_from_slice(&p);
        }
        Ok(data)
    }

    /// Run rows `rows` (indices into the query) as one model call of `n` rows
    /// (n ≥ rows.len(); extra rows repeat the last one).
    pub(super) fn run_rows(
        &self,
        q: &Query<'_>,
        rows: std::ops::Range<usize>,
        n: usize,
        out: &mut Vec<f32>,
    ) -> Result<(), PolicyError> {
        let s = &self.shape;
        let w = q.window_len(s.history);
        let row_of = |i: usize| (rows.start + i).min(rows.end - 1);
        let err = |e: String| PolicyError::Inference {
            rollout: q.rollout_ids[rows.start],
            step: q.steps[rows.start],
            message: e,
        };
        let act_norm = self
            .norm
            .as_ref()
            .filter(|m| m.act_mean.is_some() || m.act_std.is_some());
        let mut inputs: TVec<TValue> = tvec![];
        for feed in &self.sig.feeds {
            let t = match feed {
                Feed::Obs => {
                    let len = w * s.obs_dim;
                    let mut v = Vec::with_capacity(n * len);
                    for i in 0..n {
                        let r = row_of(i);
                        let src = &q.obs[r * len..(r + 1) * len];
                        match self.norm.as_ref() {
                            Some(norm) if norm.obs_mean.is_some() || norm.obs_std.is_some() => {
                                for (j, &x) in src.iter().enumerate() {
                                    let d = j % s.obs_dim;
                                    let m = norm.obs_mean.as_ref().map_or(0.0, |m| m[d]);
                                    let sd = norm.obs_std.as_ref().map_or(1.0, |m| m[d]);
                                    v.push((x - m) / sd);
                                }
                            }
                            _ => v.extend_from_slice(src),
                        }
                    }
                    Tensor::from_shape(&[n, w, s.obs_dim], &v)
                }
                Feed::PrevActions => {
                    let len = (w - 1) * s.act_dim;
                    let prev = q.prev_actions.ok_or_else(|| {
                        PolicyError::Caller(
                            "a policy taking prev_actions was queried without them".into(),
                        )
                    })?;
                    let mut v = Vec::with_capacity(n * len);
                    for i in 0..n {
                        let r = row_of(i);
                        let src = &prev[r * len..(r + 1) * len];
                        match act_norm {
                            // The model's own output space: undo the manifest's de-normalisation.
                            Some(norm) => {
                                for (j, &x) in src.iter().enumerate() {
                                    let d = j % s.act_dim;
                                    let m = norm.act_mean.as_ref().map_or(0.0, |m| m[d]);
                                    let sd = norm.act_std.as_ref().map_or(1.0, |m| m[d]);
                                    v.push((x - m) / sd);
                                }
                            }
                            None => v.extend_from_slice(src),
                        }
                    }
                    Tensor::from_shape(&[n, w - 1, s.act_dim], &v)
                }
                Feed::Images => {
                    let len = w * IMAGE_LEN;
                    let images = q.images.unwrap_or(&[]);
                    let mut v = Vec::with_capacity(n * len);
                    for i in 0..n {
                        let r = row_of(i);
                        v.extend_from_slice(&images[r * len..(r + 1) * len]);
                    }
                    let mut shape = vec![n, w];
                    shape.extend_from_slice(&IMAGE_SHAPE);
                    Tensor::from_shape(&shape, &v)
                }
                Feed::Noise => {
                    let mut v = vec![];
                    for i in 0..n {
                        let r = row_of(i);
                        self.noise_row(q.rollout_ids[r], q.steps[r], &mut v);
                    }
                    let mut shape = vec![n];
                    shape.extend_from_slice(&self.sig.noise_dims);
                    Tensor::from_shape(&shape, &v)
                }
            }
            .map_err(|e| err(format!("{e:#}")))?;
            inputs.push(t.into_tvalue());
        }
        let flat = self
            .run_plan(n, w, inputs)
            .map_err(|f| f.into_error(q.rollout_ids[rows.start], q.steps[rows.start]))?;
        let per_row = s.horizon * s.act_dim;
        let real = rows.end - rows.start;
        if flat.len() != n * per_row {
            return Err(PolicyError::WrongShape {
                got: format!("{} floats", flat.len()),
                expected: format!("[{n}, {}, {}]", s.horizon, s.act_dim),
                batch: n,
                rollout: q.rollout_ids[rows.start],
                step: q.steps[rows.start],
            });
        }
        out.extend_from_slice(&flat[..real * per_row]);
        Ok(())
    }

    /// One plan run; checks the output shape, returns it flattened.
    fn run_plan(&self, n: usize, w: usize, inputs: TVec<TValue>) -> Result<Vec<f32>, PlanFailure> {
        let s = &self.shape;
        let plan = self.model.plan(n, w).map_err(PlanFailure::Message)?;
        let result = catch_unwind(AssertUnwindSafe(|| plan.run(inputs)))
            .map_err(PlanFailure::Panic)?
            .map_err(|e| format!("{e:#}"))?;
        let first = result
            .first()
            .ok_or_else(|| "the model returned no output".to_string())?;
        let view = first
            .to_plain_array_view::<f32>()
            .map_err(|e| format!("{e:#}"))?;
        let shape = view.shape().to_vec();
        let ok = match shape.len() {
            2 => shape == [n, s.act_dim] && s.horizon == 1,
            3 => shape == [n, s.horizon, s.act_dim],
            _ => false,
        };
        if !ok {
            return Err(format!(
                "the model returned actions of shape {shape:?}; expected [{n}, {}, {}]",
                s.horizon, s.act_dim
            )
            .into());
        }
        Ok(view.iter().copied().collect())
    }
}

/// See [`OnnxPolicy::run_explicit`]. Every length is checked against the
/// model's inputs first, with a message naming the input and its shape.
pub(super) fn run_explicit(
    p: &OnnxPolicy,
    batch: usize,
    window: usize,
    obs: &[f32],
    prev_actions: Option<&[f32]>,
    noise: Option<&[f32]>,
) -> Result<Vec<f32>, PolicyError> {
    let s = &p.shape;
    let bad = |m: String| PolicyError::Caller(m);
    if batch == 0 {
        return Err(bad("the batch must be at least 1".into()));
    }
    if let Some(fixed) = p.sig.fixed_batch {
        if batch != fixed {
            return Err(bad(format!(
                "the model fixes its batch dimension to {fixed}; run it at batch {fixed}"
            )));
        }
    }
    let windows = if p.sig.grow {
        1..=s.history
    } else {
        s.history..=s.history
    };
    if !windows.contains(&window) {
        return Err(bad(format!(
            "window {window} is not one the model is run with: {} (history k = {}, window `{}`)",
            if p.sig.grow {
                format!("1 to {}", s.history)
            } else {
                s.history.to_string()
            },
            s.history,
            if p.sig.grow { "grow" } else { "pad" },
        )));
    }
    for (feed, given) in [(Feed::PrevActions, prev_actions), (Feed::Noise, noise)] {
        // Previous actions of a window of 1 are empty: null is fine there.
        let empty = feed == Feed::PrevActions && window == 1;
        match (p.has(feed), given.is_some()) {
            (true, false) if !empty => {
                return Err(bad(format!(
                    "the model takes `{}`; give it (not null)",
                    feed.name()
                )))
            }
            (false, true) => {
                return Err(bad(format!(
                    "the model has no `{}` input; give null",
                    feed.name()
                )))
            }
            _ => {}
        }
    }
    let mut inputs: TVec<TValue> = tvec![];
    for feed in &p.sig.feeds {
        let (shape, data): (Vec<usize>, &[f32]) = match feed {
            Feed::Obs => (vec![batch, window, s.obs_dim], obs),
            Feed::PrevActions => (
                vec![batch, window - 1, s.act_dim],
                prev_actions.unwrap_or_default(),
            ),
            Feed::Noise => {
                let mut sh = vec![batch];
                sh.extend_from_slice(&p.sig.noise_dims);
                (sh, noise.unwrap_or_default())
            }
            Feed::Images => return Err(bad("run_explicit takes state policies only".into())),
        };
        let want: usize = shape.iter().product();
        if data.len() != want {
            return Err(bad(format!(
                "`{}` has {} values; its shape {shape:?} needs {want}",
                feed.name(),
                data.len()
            )));
        }
        let t = Tensor::from_shape(&shape, data).map_err(|e| bad(format!("{e:#}")))?;
        inputs.push(t.into_tvalue());
    }
    p.run_plan(batch, window, inputs)
        .map_err(|f| f.into_error(0, 0))
}

/// Why a plan run failed.
enum PlanFailure {
    Message(String),
    Panic(Box<dyn std::any::Any + Send>),
}

impl From<String> for PlanFailure {
    fn from(m: String) -> Self {
        PlanFailure::Message(m)
    }
}

impl PlanFailure {
    /// The error for the rows starting with (rollout, step): memory exhaustion
    /// for a failed allocation, else an inference error with tract's message.
    fn into_error(self, rollout: u64, step: u64) -> PolicyError {
        let err = |message: String| PolicyError::Inference {
            rollout,
            step,
            message,
        };
        match self {
            PlanFailure::Message(m) => err(m),
            PlanFailure::Panic(p) => panic_error(
                p,
                format!("in the query of rollout {rollout} at step {step}"),
                |msg| err(format!("the ONNX runtime panicked ({msg})")),
            ),
        }
    }
}
