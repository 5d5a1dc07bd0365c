//! ONNX policies run with tract (docs/submission.md, docs/export.md).
//!
//! Inputs (by name): `obs` float32 `[B, w, obs_dim]` (state policies; optional for
//! image policies), `images` float32 `[B, w, 2, 3, 96, 96]` (image policies),
//! optional `prev_actions` float32 `[B, w−1, act_dim]` (the rollout's previous
//! actions), optional `noise` float32 `[B, ...]` with fixed non-batch dimensions,
//! filled from standard normal samples of a seeded ChaCha8 stream per (seed,
//! rollout, step). w = k, or 1..=k at episode start for `"window": "grow"`.
//! One output: float32 `[B, H, act_dim]` or `[B, act_dim]` (H = 1).
//!
//! The job is split three ways: [`admit`] checks the file and the manifest,
//! `load` analyses the graph and makes plans per (batch, window) (with `fast`
//! swapping a few slow tract kernels for ours), `run` builds the inputs and
//! runs the batch on every core.

mod admit;
mod fast;
mod load;
mod run;

pub use admit::{admit, ADMISSION_BATCH, MAX_DECLARED_WEIGHT_BYTES};

use crate::{ActionChunks, Policy, PolicyError, PolicyShape, Query};
use admit::{Feed, Signature};
use d3il_protocol::{PolicyManifest, TaskSpec, WindowMode};
use std::panic::{catch_unwind, AssertUnwindSafe};

struct Norm {
    obs_mean: Option<Vec<f32>>,
    obs_std: Option<Vec<f32>>,
    act_mean: Option<Vec<f32>>,
    act_std: Option<Vec<f32>>,
}

pub struct OnnxPolicy {
    model: load::Model,
    sig: Signature,
    shape: PolicyShape,
    seed: u64,
    norm: Option<Norm>,
    /// Threads one call is split across (one plan run per thread).
    threads: usize,
}

impl std::fmt::Debug for OnnxPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxPolicy")
            .field("shape", &self.shape)
            .field("sig", &self.sig)
            .field("threads", &self.threads)
            .finish()
    }
}

/// A panic in tract becomes an error: memory exhaustion (an allocation that
/// failed under the worker's address-space limit) or the runtime's message.
fn panic_error(
    p: Box<dyn std::any::Any + Send>,
    during: String,
    other: impl FnOnce(String) -> PolicyError,
) -> PolicyError {
    let msg = crate::error::panic_text(p.as_ref());
    if crate::error::is_out_of_memory(&msg) {
        PolicyError::OutOfMemory {
            during,
            detail: msg,
        }
    } else {
        other(msg)
    }
}

impl OnnxPolicy {
    /// Load and validate a policy from the bytes of an .onnx file and its manifest
    /// against the task's dimensions. `seed` drives the `noise` input. Loading
    /// does not run the graph (a graph that never finishes is stopped by the
    /// worker's limits while running the rollouts); [`admit`] adds the test
    /// inference ([`OnnxPolicy::test_inference`]).
    pub fn load(
        bytes: &[u8],
        manifest: &PolicyManifest,
        task: &TaskSpec,
        seed: u64,
    ) -> Result<Self, PolicyError> {
        // tract panics on a few malformed inputs (unimplemented data types);
        // a submission must never take the evaluator down with it.
        let p = catch_unwind(AssertUnwindSafe(|| {
            Self::load_inner(bytes, manifest, task, seed)
        }))
        .map_err(|p| {
            panic_error(p, "while loading the model".into(), |msg| {
                PolicyError::Unsupported(format!(
                    "the ONNX runtime could not handle this model ({msg})"
                ))
            })
        })??;
        Ok(p)
    }

    fn load_inner(
        bytes: &[u8],
        manifest: &PolicyManifest,
        task: &TaskSpec,
        seed: u64,
    ) -> Result<Self, PolicyError> {
        let (proto, sig) = admit::inspect(bytes, manifest, task)?;
        let norm = manifest.normalisation.as_ref().map(|n| Norm {
            obs_mean: n.obs_mean.clone(),
            obs_std: n.obs_std.clone(),
            act_mean: n.act_mean.clone(),
            act_std: n.act_std.clone(),
        });
        let model = load::Model::build(&proto, &sig, manifest, task)?;
        Ok(OnnxPolicy {
            model,
            sig,
            shape: PolicyShape {
                history: manifest.history,
                horizon: manifest.horizon,
                execute: manifest.execute,
                obs_dim: task.obs_dim,
                act_dim: task.act_dim,
                obs_type: manifest.obs_type,
            },
            seed,
            norm,
            threads: std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
                .min(8),
        })
    }

    /// Runs every window length in use at batch [`ADMISSION_BATCH`] on zero
    /// observations, so a graph that loads but cannot run (e.g. one optimised
    /// into shapes that only hold at batch 1) is refused with tract's reason.
    /// Then runs the full window again with the second row's inputs changed:
    /// a graph whose first row then gets other actions mixes the rows of the
    /// batch, and is refused (its results would depend on which rollouts share
    /// a call, and a deterministic one is simulated once per initial state).
    pub fn test_inference(&self) -> Result<(), PolicyError> {
        let s = self.shape;
        let windows: Vec<usize> = if self.sig.grow {
            (1..=s.history).collect()
        } else {
            vec![s.history]
        };
        let b = ADMISSION_BATCH;
        let ids: Vec<u64> = (0..b as u64).collect();
        let steps = vec![0u64; b];
        // Row 0 is all zeros; row 1 is zeros, or `other` in the second run.
        let run = |w: usize, other: f32| -> Result<Vec<f32>, PolicyError> {
            let rows = |len: usize| -> Vec<f32> {
                let mut v = vec![0.0f32; b * len];
                v[len..].fill(other);
                v
            };
            let obs = rows(w * s.obs_dim);
            let images = rows(w * crate::IMAGE_LEN);
            let prev = rows((w - 1) * s.act_dim);
            let q = Query {
                rollout_ids: &ids,
                steps: &steps,
                obs: &obs,
                images: (s.obs_type == d3il_protocol::ObsType::Image).then_some(&images[..]),
                window: Some(w),
                prev_actions: Some(&prev),
            };
            let mut out = Vec::new();
            self.run_rows(&q, 0..b, b, &mut out).map_err(|e| match e {
                // Out of memory stays a memory-limit error.
                PolicyError::Inference { message, .. } => PolicyError::Unsupported(format!(
                    "the model failed a test inference at batch {b} with a window of {w} observation(s): {message}"
                )),
                other => other,
            })?;
            Ok(out)
        };
        let mut zeros = Vec::new();
        for &w in &windows {
            zeros = run(w, 0.0)?;
        }
        if self.sig.fixed_batch.is_none() {
            let changed = run(s.history, 0.5)?;
            let row = s.horizon * s.act_dim;
            let same = zeros[..row]
                .iter()
                .zip(&changed[..row])
                .all(|(a, b)| a.to_bits() == b.to_bits());
            if !same {
                return Err(PolicyError::Unsupported(
                    "the actions of one row of a test batch changed when only the other row's inputs changed: the graph mixes the rows of the batch (batch statistics, e.g. a BatchNorm exported in training mode: export after model.eval(); or a reduction over the batch axis). The evaluator runs many rollouts in one call, so each row's actions must depend on that row's inputs alone".into(),
                ));
            }
        }
        Ok(())
    }

    /// Threads one call is split across (default: the machine's cores, at most 8).
    pub fn set_threads(&mut self, n: usize) {
        self.threads = n.max(1);
    }

    /// Runs the graph on inputs given in full, bypassing the evaluator's noise
    /// and the manifest's normalisation: `noise` and `prev_actions` must be given
    /// when the model takes them. Returns the raw output, `[B, H, act_dim]`
    /// flattened. For comparing with another runtime on recorded inputs.
    pub fn run_explicit(
        &self,
        batch: usize,
        window: usize,
        obs: &[f32],
        prev_actions: Option<&[f32]>,
        noise: Option<&[f32]>,
    ) -> Result<Vec<f32>, PolicyError> {
        run::run_explicit(self, batch, window, obs, prev_actions, noise)
    }

    /// Whether the model reads an input named `name`.
    fn has(&self, feed: Feed) -> bool {
        self.sig.feeds.contains(&feed)
    }
}

impl Policy for OnnxPolicy {
    fn shape(&self) -> PolicyShape {
        self.shape
    }

    fn reset(&mut self, _rollout_ids: &[u64]) -> Result<(), PolicyError> {
        // Stateless: history lives in the evaluator, noise is keyed by rollout/step.
        Ok(())
    }

    fn infer(&mut self, q: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        q.check(&self.shape)?;
        let s = self.shape;
        let mut data = self.run_query(q)?;
        if let Some(norm) = &self.norm {
            if norm.act_mean.is_some() || norm.act_std.is_some() {
                for (j, a) in data.iter_mut().enumerate() {
                    let d = j % s.act_dim;
                    let sd = norm.act_std.as_ref().map_or(1.0, |m| m[d]);
                    let m = norm.act_mean.as_ref().map_or(0.0, |m| m[d]);
                    *a = *a * sd + m;
                }
            }
        }
        Ok(ActionChunks {
            batch: q.batch(),
            horizon: s.horizon,
            act_dim: s.act_dim,
            data,
        })
    }

    fn window(&self) -> WindowMode {
        if self.sig.grow {
            WindowMode::Grow
        } else {
            WindowMode::Pad
        }
    }

    fn takes_prev_actions(&self) -> bool {
        self.has(Feed::PrevActions)
    }

    fn self_test(&mut self) -> Result<(), PolicyError> {
        self.test_inference()
    }

    /// Without a `noise` input the graph has no randomness (admission refuses
    /// random operators), and a row's actions do not depend on the rest of
    /// the batch ([`load::bucket`]).
    fn deterministic(&self) -> bool {
        !self.has(Feed::Noise)
    }
}
