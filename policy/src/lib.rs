//! Policies for the D3IL evaluator.
//!
//! The lockstep engine queries a [`Policy`] with the observations of all B live
//! rollouts at once ([`Query`]) and gets B action chunks of H actions back
//! ([`ActionChunks`]); it executes the first E ≤ H of each chunk before querying
//! that rollout again. Implementations: [`OnnxPolicy`] (tract) and
//! [`RemotePolicy`] (WebSocket + msgpack, docs/remote-protocol.md).
//!
//! Layout conventions (all row-major float32):
//! * observations `[B, w, obs_dim]`, oldest first, newest at index w−1; w = k, the
//!   window padded at episode start by repeating the first observation, or, for a
//!   policy whose [`Policy::window`] is [`WindowMode::Grow`], w = 1, 2, …, k at
//!   episode start ([`HistoryBuffer`]);
//! * previous actions `[B, w−1, act_dim]` (policies that take them), oldest first;
//! * images `[B, k, 2, 3, 96, 96]` (image policies only);
//! * actions `[B, H, act_dim]`.

#![forbid(unsafe_code)]

mod error;
pub mod onnx;
pub mod remote;
pub mod wire;

pub use error::PolicyError;
pub use onnx::OnnxPolicy;
pub use remote::RemotePolicy;

pub use d3il_protocol::WindowMode;
use d3il_protocol::{ObsType, TaskId};
use std::collections::VecDeque;

/// Shape of the camera input of image policies per history entry: 2 cameras,
/// 3 channels, 96 × 96 pixels.
pub const IMAGE_SHAPE: [usize; 4] = [2, 3, 96, 96];
/// Number of floats of one image history entry.
pub const IMAGE_LEN: usize = 2 * 3 * 96 * 96;

/// History length k, chunk length H and executed actions E of a policy, plus
/// the per-step dimensions it was validated against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PolicyShape {
    /// k: observations per query.
    pub history: usize,
    /// H: actions returned per query.
    pub horizon: usize,
    /// E ≤ H: actions executed before the rollout is queried again.
    pub execute: usize,
    pub obs_dim: usize,
    pub act_dim: usize,
    pub obs_type: ObsType,
}

/// One batched query: B rollouts, their step indices and observation windows.
/// Every row of one query has the same window length w.
#[derive(Debug, Clone, Copy)]
pub struct Query<'a> {
    /// Ids of the B rollouts (stable for a rollout's lifetime; any numbering).
    pub rollout_ids: &'a [u64],
    /// Environment step index of each rollout (0 at episode start).
    pub steps: &'a [u64],
    /// `[B, w, obs_dim]`.
    pub obs: &'a [f32],
    /// `[B, w, 2, 3, 96, 96]` for image policies, `None` otherwise.
    pub images: Option<&'a [f32]>,
    /// Window length w of every row; `None` means the policy's k.
    pub window: Option<usize>,
    /// `[B, w−1, act_dim]`: the last w−1 actions each rollout executed, oldest
    /// first (zeros before the episode's first action in a padded window);
    /// given to policies whose [`Policy::takes_prev_actions`] is true.
    pub prev_actions: Option<&'a [f32]>,
}

impl<'a> Query<'a> {
    pub fn new(rollout_ids: &'a [u64], steps: &'a [u64], obs: &'a [f32]) -> Self {
        Query {
            rollout_ids,
            steps,
            obs,
            images: None,
            window: None,
            prev_actions: None,
        }
    }

    pub fn batch(&self) -> usize {
        self.rollout_ids.len()
    }

    /// The window length w of this query's rows for a policy of history `k`.
    pub fn window_len(&self, k: usize) -> usize {
        self.window.unwrap_or(k)
    }

    /// Checks the buffer lengths against a policy shape (evaluator-side bugs).
    pub fn check(&self, shape: &PolicyShape) -> Result<(), PolicyError> {
        let b = self.batch();
        if self.steps.len() != b {
            return Err(PolicyError::Caller(format!(
                "query has {b} rollout ids but {} step indices",
                self.steps.len()
            )));
        }
        let w = self.window_len(shape.history);
        if w == 0 || w > shape.history {
            return Err(PolicyError::Caller(format!(
                "query window {w} is outside 1..={}",
                shape.history
            )));
        }
        let want = b * w * shape.obs_dim;
        if self.obs.len() != want {
            return Err(PolicyError::Caller(format!(
                "query observation buffer has {} floats; expected B·w·obs_dim = {b}·{w}·{} = {want}",
                self.obs.len(),
                shape.obs_dim
            )));
        }
        if let Some(p) = self.prev_actions {
            let want = b * (w - 1) * shape.act_dim;
            if p.len() != want {
                return Err(PolicyError::Caller(format!(
                    "query previous-action buffer has {} floats; expected B·(w−1)·act_dim = {want}",
                    p.len()
                )));
            }
        }
        if shape.obs_type == ObsType::Image {
            let want = b * w * IMAGE_LEN;
            match self.images {
                Some(im) if im.len() == want => {}
                Some(im) => {
                    return Err(PolicyError::Caller(format!(
                        "query image buffer has {} floats; expected B·k·2·3·96·96 = {want}",
                        im.len()
                    )))
                }
                None => {
                    return Err(PolicyError::Caller(
                        "image policy queried without images".into(),
                    ))
                }
            }
        }
        Ok(())
    }

    /// (rollout id, step) of row 0, for error messages.
    fn first(&self) -> (u64, u64) {
        (
            self.rollout_ids.first().copied().unwrap_or(0),
            self.steps.first().copied().unwrap_or(0),
        )
    }
}

/// B action chunks, `[B, H, act_dim]` row-major.
#[derive(Debug, Clone, PartialEq)]
pub struct ActionChunks {
    pub batch: usize,
    pub horizon: usize,
    pub act_dim: usize,
    pub data: Vec<f32>,
}

impl ActionChunks {
    /// The H actions of row `row` (`H·act_dim` floats).
    pub fn chunk(&self, row: usize) -> &[f32] {
        let n = self.horizon * self.act_dim;
        &self.data[row * n..(row + 1) * n]
    }

    /// Action `h` of row `row` (`act_dim` floats).
    pub fn action(&self, row: usize, h: usize) -> &[f32] {
        let start = (row * self.horizon + h) * self.act_dim;
        &self.data[start..start + self.act_dim]
    }
}

/// A policy the lockstep engine can query. Not required to be `Sync`: the engine
/// calls it from one thread, once per lockstep iteration.
pub trait Policy: Send {
    /// k, H, E and the dimensions the policy was validated against.
    fn shape(&self) -> PolicyShape;

    /// New episodes start for these rollouts (clear any per-rollout state).
    fn reset(&mut self, rollout_ids: &[u64]) -> Result<(), PolicyError>;

    /// One batched query; returns `[B, H, act_dim]`. Implementations check the
    /// shape of what they return; call [`validate_actions`] before using the
    /// actions (they may be NaN).
    fn infer(&mut self, query: &Query<'_>) -> Result<ActionChunks, PolicyError>;

    /// How the observation window starts an episode: padded to k (default) or
    /// growing from 1 to k, one query per window length.
    fn window(&self) -> WindowMode {
        WindowMode::Pad
    }

    /// Whether queries must carry [`Query::prev_actions`].
    fn takes_prev_actions(&self) -> bool {
        false
    }

    /// A cheap test inference before the first rollout, so a policy that
    /// cannot run fails with its reason rather than at rollout 0 (default: none).
    fn self_test(&mut self) -> Result<(), PolicyError> {
        Ok(())
    }

    /// Whether a row's actions are a function of the row's own inputs alone
    /// (observation window, images, previous actions), bit for bit, whatever
    /// else is in the batch and whatever the rollout id and step. The engine
    /// then simulates the rollouts of one initial state once. Default: no
    /// (remote and scripted policies may draw random numbers or keep state
    /// per rollout).
    fn deterministic(&self) -> bool {
        false
    }
}

impl<P: Policy + ?Sized> Policy for Box<P> {
    fn shape(&self) -> PolicyShape {
        (**self).shape()
    }
    fn reset(&mut self, rollout_ids: &[u64]) -> Result<(), PolicyError> {
        (**self).reset(rollout_ids)
    }
    fn infer(&mut self, query: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        (**self).infer(query)
    }
    fn window(&self) -> WindowMode {
        (**self).window()
    }
    fn takes_prev_actions(&self) -> bool {
        (**self).takes_prev_actions()
    }
    fn deterministic(&self) -> bool {
        (**self).deterministic()
    }
    fn self_test(&mut self) -> Result<(), PolicyError> {
        (**self).self_test()
    }
}

/// Checks that `chunks` has the shape the query and policy demand and that the
/// first `execute` actions of every chunk are finite; the error names the rollout
/// and step. Run this before any action reaches MuJoCo.
pub fn validate_actions(
    query: &Query<'_>,
    shape: &PolicyShape,
    chunks: &ActionChunks,
) -> Result<(), PolicyError> {
    let b = query.batch();
    let (rollout, step) = query.first();
    if chunks.batch != b
        || chunks.horizon != shape.horizon
        || chunks.act_dim != shape.act_dim
        || chunks.data.len() != b * shape.horizon * shape.act_dim
    {
        return Err(PolicyError::WrongShape {
            got: format!(
                "actions [{}, {}, {}] ({} floats)",
                chunks.batch,
                chunks.horizon,
                chunks.act_dim,
                chunks.data.len()
            ),
            expected: format!("[{b}, {}, {}]", shape.horizon, shape.act_dim),
            batch: b,
            rollout,
            step,
        });
    }
    for row in 0..b {
        for h in 0..shape.execute.min(shape.horizon) {
            for (c, &v) in chunks.action(row, h).iter().enumerate() {
                if !v.is_finite() {
                    return Err(PolicyError::NonFinite {
                        rollout: query.rollout_ids[row],
                        step: query.steps[row] + h as u64,
                        action: h,
                        component: c,
                        value: v,
                    });
                }
            }
        }
    }
    Ok(())
}

/// The last k observations of one rollout. In [`WindowMode::Pad`] the window is
/// padded at episode start by repeating the first observation, so a k = 5 policy
/// sees `[o0, o0, o0, o0, o0]`, then `[o0, o0, o0, o0, o1]`, …; in
/// [`WindowMode::Grow`] it grows as the reference agents' deques do: `[o0]`,
/// `[o0, o1]`, … up to k entries.
#[derive(Debug, Clone)]
pub struct HistoryBuffer {
    k: usize,
    dim: usize,
    grow: bool,
    window: VecDeque<Vec<f32>>,
}

impl HistoryBuffer {
    /// `k` ≥ 1 entries of `dim` floats each, padded at episode start.
    pub fn new(k: usize, dim: usize) -> Self {
        Self::with_mode(k, dim, WindowMode::Pad)
    }

    /// `k` ≥ 1 entries of `dim` floats each, with the given episode-start semantics.
    pub fn with_mode(k: usize, dim: usize, mode: WindowMode) -> Self {
        HistoryBuffer {
            k: k.max(1),
            dim,
            grow: mode == WindowMode::Grow,
            window: VecDeque::with_capacity(k.max(1)),
        }
    }

    /// The window's length k: a query reads the k newest entries.
    pub fn capacity(&self) -> usize {
        self.k
    }

    /// Entries in the window now (k once full; fewer at episode start when growing).
    pub fn len(&self) -> usize {
        self.window.len()
    }

    /// Forget everything (new episode).
    pub fn reset(&mut self) {
        self.window.clear();
    }

    pub fn is_empty(&self) -> bool {
        self.window.is_empty()
    }

    /// Append the newest observation; the first one after a reset fills the window.
    pub fn push(&mut self, obs: &[f32]) -> Result<(), PolicyError> {
        if obs.len() != self.dim {
            return Err(PolicyError::Caller(format!(
                "history entry has {} floats; expected {}",
                obs.len(),
                self.dim
            )));
        }
        if self.window.is_empty() && !self.grow {
            for _ in 0..self.k {
                self.window.push_back(obs.to_vec());
            }
        } else if self.window.len() < self.k {
            self.window.push_back(obs.to_vec());
        } else {
            // Reuse the oldest allocation for the newest entry.
            let mut v = self.window.pop_front().unwrap_or_default();
            v.clear();
            v.extend_from_slice(obs);
            self.window.push_back(v);
        }
        Ok(())
    }

    /// Append the window (oldest first, `k·dim` floats) to `out`.
    pub fn write_window(&self, out: &mut Vec<f32>) -> Result<(), PolicyError> {
        if self.window.is_empty() {
            return Err(PolicyError::Caller(
                "history read before the first observation of the episode".into(),
            ));
        }
        for e in &self.window {
            out.extend_from_slice(e);
        }
        Ok(())
    }
}

/// What the observation vector of a task contains, for error messages
/// (docs/original-d3il.md §10.2.3, §10.3.3, §10.4.3; docs/original-d3il.md §11.1.3, §11.2.3, §11.3.3).
pub fn obs_description(task: TaskId) -> &'static str {
    match task {
        TaskId::Avoiding => "previous command xy + observation xy",
        TaskId::Aligning => "previous command xyz + observation",
        TaskId::Pushing | TaskId::Sorting2 | TaskId::Sorting4 | TaskId::Sorting6 => {
            "previous command xy + observation"
        }
        TaskId::Stacking => "previous joint command + gripper + box states",
        TaskId::Inserting => "previous command xy + observation",
    }
}

/// What one action of a task contains, for error messages.
pub fn act_description(task: TaskId) -> &'static str {
    match task {
        TaskId::Aligning => "xyz delta of the desired position",
        TaskId::Stacking => "joint deltas + gripper",
        _ => "xy delta of the desired position",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn history_pads_with_first_then_slides() {
        let mut h = HistoryBuffer::new(3, 2);
        let mut out = vec![];
        assert!(h.write_window(&mut out).is_err());
        h.push(&[1.0, 2.0]).unwrap();
        h.write_window(&mut out).unwrap();
        assert_eq!(out, [1.0, 2.0, 1.0, 2.0, 1.0, 2.0]);
        h.push(&[3.0, 4.0]).unwrap();
        out.clear();
        h.write_window(&mut out).unwrap();
        assert_eq!(out, [1.0, 2.0, 1.0, 2.0, 3.0, 4.0]);
        h.push(&[5.0, 6.0]).unwrap();
        h.push(&[7.0, 8.0]).unwrap();
        out.clear();
        h.write_window(&mut out).unwrap();
        assert_eq!(out, [3.0, 4.0, 5.0, 6.0, 7.0, 8.0]);
        h.reset();
        h.push(&[9.0, 9.5]).unwrap();
        out.clear();
        h.write_window(&mut out).unwrap();
        assert_eq!(out, [9.0, 9.5, 9.0, 9.5, 9.0, 9.5]);
        let e = h.push(&[1.0]).unwrap_err();
        assert!(e.to_string().contains("expected 2"), "{e}");
    }

    #[test]
    fn growing_history_starts_with_one_entry() {
        let mut h = HistoryBuffer::with_mode(3, 1, WindowMode::Grow);
        let mut lens = vec![];
        for i in 0..5 {
            h.push(&[i as f32]).unwrap();
            lens.push(h.len());
        }
        assert_eq!(lens, [1, 2, 3, 3, 3]);
        let mut out = vec![];
        h.write_window(&mut out).unwrap();
        assert_eq!(out, [2.0, 3.0, 4.0]);
        h.reset();
        h.push(&[9.0]).unwrap();
        out.clear();
        h.write_window(&mut out).unwrap();
        assert_eq!(out, [9.0]);
    }

    fn shape() -> PolicyShape {
        PolicyShape {
            history: 1,
            horizon: 2,
            execute: 1,
            obs_dim: 1,
            act_dim: 2,
            obs_type: ObsType::State,
        }
    }

    #[test]
    fn validation_names_rollout_and_step() {
        let ids = [10, 11];
        let steps = [5, 7];
        let obs = [0.0, 0.0];
        let q = Query::new(&ids, &steps, &obs);
        let mut a = ActionChunks {
            batch: 2,
            horizon: 2,
            act_dim: 2,
            data: vec![0.0; 8],
        };
        validate_actions(&q, &shape(), &a).unwrap();
        // Non-executed chunk entries may be anything.
        a.data[7] = f32::NAN;
        validate_actions(&q, &shape(), &a).unwrap();
        a.data[5] = f32::INFINITY;
        let e = validate_actions(&q, &shape(), &a).unwrap_err();
        let m = e.to_string();
        assert!(
            m.contains("rollout 11") && m.contains("step 7") && m.contains("inf"),
            "{m}"
        );
        assert_eq!(e.kind(), d3il_protocol::ErrorKind::BadAction);
        let short = ActionChunks {
            batch: 2,
            horizon: 1,
            act_dim: 2,
            data: vec![0.0; 4],
        };
        let m = validate_actions(&q, &shape(), &short)
            .unwrap_err()
            .to_string();
        assert!(
            m.contains("expected [2, 2, 2]") && m.contains("rollout 10"),
            "{m}"
        );
    }

    #[test]
    fn query_check_catches_caller_bugs() {
        let q = Query::new(&[1, 2], &[0, 0], &[0.0; 3]);
        let e = q.check(&shape()).unwrap_err();
        assert_eq!(e.kind(), d3il_protocol::ErrorKind::Internal);
        assert!(
            e.to_string().contains("expected B·w·obs_dim = 2·1·1 = 2"),
            "{e}"
        );
    }
}
