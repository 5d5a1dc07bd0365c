//! Turning an admitted ONNX file into runnable plans.
//!
//! The graph is analysed once with symbolic batch `B` and window `T` ([`Model`]);
//! each (batch, window) in use then gets its own plan with the symbols bound
//! *before* optimisation (`into_typed` → bind → `into_optimized`). Graphs whose
//! sampling loop builds `torch.full((B,), t)` timesteps only work this way:
//! optimising with a symbolic batch folds the timestep embedding into a `[1, d]`
//! constant that no longer concatenates with the `[B, …]` tensors. Plans are
//! cached; batch sizes are rounded up to a few buckets ([`bucket`]) so the
//! shrinking live set at the end of an evaluation reuses them.

use super::admit::{mismatch, Feed, Signature};
use crate::{act_description, PolicyError, IMAGE_SHAPE};
use d3il_protocol::{PolicyManifest, TaskSpec};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use tract_onnx::pb;
use tract_onnx::prelude::*;

pub(super) type Plan = Arc<TypedRunnableModel>;

/// The analysed graph and its plans per (batch, window).
pub(super) struct Model {
    typed: TypedModel,
    batch: Symbol,
    window: Symbol,
    plans: Mutex<HashMap<(usize, usize), Plan>>,
    /// tract's cost estimate of one row at the full window (multiply-adds
    /// plus other element operations; `u64::MAX` when it cannot tell).
    work_per_row: u64,
    /// Bytes of the largest intermediate tensor of one row at the full
    /// window (0 when it cannot tell).
    largest_row_bytes: usize,
}

/// Batch sizes plans are made for: a call with b rows runs on the plan of the
/// smallest bucket ≥ b, padded by repeating its last row.
///
/// There is no bucket of one row: tract runs a one-row plan through other
/// kernels (matrix–vector products) whose rounding differs from its plans of
/// two or more rows, which agree with each other bit for bit. A row that ran
/// alone (the only rollout querying at that step, or the last row of a call
/// split across threads, which depends on the host's core count) would get
/// other actions than in company, so a single row runs padded to two and a
/// row's actions depend only on its inputs (`tests/policies/agent_fixtures.rs`).
pub(super) fn bucket(b: usize) -> usize {
    const SMALL: [usize; 10] = [2, 3, 4, 6, 8, 12, 16, 24, 32, 48];
    if let Some(&s) = SMALL.iter().find(|&&s| s >= b) {
        return s;
    }
    // 64, 96, 128, 192, …
    let mut s = 64;
    loop {
        if s >= b {
            return s;
        }
        if s * 3 / 2 >= b {
            return s * 3 / 2;
        }
        s *= 2;
    }
}

/// The usual causes of a graph that tract cannot analyse or plan once the
/// window (or batch) is a symbol, and their fixes; added to those refusals,
/// whose own text names tract's nodes rather than the Python that made them.
pub(super) const FROZEN_SIZE_HINT: &str = "The usual causes: a Python int computed from a tensor \
     size in `forward` (e.g. `int(x.size()[1] / 2)`) is frozen by tracing to the example \
     input's window (or batch), so the graph only runs at that size: export with the window \
     symbolic (the exporter in d3il_client.agents does), or compute it with tensor \
     operations; or a \
     suffix slice of the noise such as `noise[:, i, K-T:]`: slice prefixes, `noise[:, i, :T]`. \
     See docs/export.md, \"Traps, with their messages and fixes\".";

fn unsupported(e: impl std::fmt::Display) -> PolicyError {
    PolicyError::Unsupported(e.to_string())
}

impl Model {
    /// Declares the inputs' shapes with the symbols and analyses the graph.
    pub(super) fn build(
        proto: &pb::ModelProto,
        sig: &Signature,
        manifest: &PolicyManifest,
        task: &TaskSpec,
    ) -> Result<Self, PolicyError> {
        let onnx = tract_onnx::onnx();
        let mut model = onnx
            .model_for_proto_model(proto)
            .map_err(|e| unsupported(format!("{e:#}")))?;
        let batch = model.symbols.sym("B");
        let window = model.symbols.sym("T");
        let b_dim: TDim = match sig.fixed_batch {
            Some(n) => n.to_dim(),
            None => batch.clone().into(),
        };
        let t_dim: TDim = if sig.grow {
            window.clone().into()
        } else {
            manifest.history.to_dim()
        };
        for (i, feed) in sig.feeds.iter().enumerate() {
            let mut dims: Vec<TDim> = vec![b_dim.clone()];
            match feed {
                Feed::Obs => {
                    dims.push(t_dim.clone());
                    dims.push(task.obs_dim.to_dim());
                }
                Feed::Images => {
                    dims.push(t_dim.clone());
                    dims.extend(IMAGE_SHAPE.iter().map(|d| d.to_dim()));
                }
                Feed::PrevActions => {
                    dims.push(t_dim.clone() - 1);
                    dims.push(task.act_dim.to_dim());
                }
                Feed::Noise => dims.extend(sig.noise_dims.iter().map(|d| d.to_dim())),
            }
            // Input order in tract follows the graph's non-initializer inputs.
            model
                .set_input_fact(i, f32::fact(dims).into())
                .map_err(|e| unsupported(format!("{e:#}")))?;
        }
        let outputs = model.output_outlets().map(|o| o.len()).unwrap_or(0);
        if outputs != 1 {
            return Err(mismatch(format!(
                "the model has {outputs} outputs; it must have exactly one, the actions [B, H, act_dim] or [B, act_dim]"
            )));
        }
        let typed = model.into_typed().map_err(|e| {
            unsupported(format!(
                "tract could not analyse the graph with the declared input shapes ({}): {e:#}. {FROZEN_SIZE_HINT}",
                declared_shapes(sig, manifest, task)
            ))
        })?;
        let out_name = proto
            .graph
            .as_ref()
            .and_then(|g| g.output.first())
            .map(|o| o.name.clone())
            .unwrap_or_else(|| "output".into());
        check_output(&typed, &out_name, manifest, task)?;
        let (work_per_row, largest_row_bytes) =
            row_costs(&typed, &batch, &window, manifest.history);
        Ok(Model {
            typed,
            batch,
            window,
            plans: Mutex::new(HashMap::new()),
            work_per_row,
            largest_row_bytes,
        })
    }

    /// tract's cost estimate of one row at the full window.
    pub(super) fn work_per_row(&self) -> u64 {
        self.work_per_row
    }

    /// Bytes of the largest intermediate tensor of one row (0: unknown).
    pub(super) fn largest_row_bytes(&self) -> usize {
        self.largest_row_bytes
    }

    /// The plan for `batch` rows (a bucket size, or the fixed batch) and window `w`.
    pub(super) fn plan(&self, batch: usize, w: usize) -> Result<Plan, String> {
        let key = (batch, w);
        if let Some(p) = self.plans.lock().map_err(|e| e.to_string())?.get(&key) {
            return Ok(p.clone());
        }
        let subs: HashMap<Symbol, TDim> = [
            (self.batch.clone(), batch.to_dim()),
            (self.window.clone(), w.to_dim()),
        ]
        .into_iter()
        .collect();
        let plan = self
            .typed
            .set_symbols(&subs)
            .and_then(|m| m.into_optimized())
            .and_then(|m| {
                // Our kernels where they apply; tract's plan as it is if the
                // swap fails on some graph.
                let mut fast = m.clone();
                match super::fast::speed_up(&mut fast) {
                    Ok(()) => fast.into_runnable(),
                    Err(_) => m.into_runnable(),
                }
            })
            .map_err(|e| {
                format!(
                    "tract could not prepare the graph for batch {batch}, window {w}: {e:#}. {FROZEN_SIZE_HINT}"
                )
            })?;
        self.plans
            .lock()
            .map_err(|e| e.to_string())?
            .insert(key, plan.clone());
        Ok(plan)
    }
}

/// The input shapes the graph was analysed with, e.g. `obs [B, T, 20]`
/// (`B` the batch, `T` the window when it grows).
fn declared_shapes(sig: &Signature, manifest: &PolicyManifest, task: &TaskSpec) -> String {
    let b = match sig.fixed_batch {
        Some(n) => n.to_string(),
        None => "B".into(),
    };
    let t = if sig.grow {
        "T".to_string()
    } else {
        manifest.history.to_string()
    };
    sig.feeds
        .iter()
        .map(|f| {
            let dims = match f {
                Feed::Obs => format!("{b}, {t}, {}", task.obs_dim),
                Feed::Images => format!(
                    "{b}, {t}, {}",
                    IMAGE_SHAPE.map(|d| d.to_string()).join(", ")
                ),
                Feed::PrevActions => format!("{b}, {t} - 1, {}", task.act_dim),
                Feed::Noise => std::iter::once(b.clone())
                    .chain(sig.noise_dims.iter().map(|d| d.to_string()))
                    .collect::<Vec<_>>()
                    .join(", "),
            };
            format!("{} [{dims}]", f.name())
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// tract's cost estimate of one row (batch 1, window `k`), summed over the
/// graph's nodes (`u64::MAX` when some cost is not a number), and the bytes of
/// the row's largest intermediate tensor (0 when unknown).
fn row_costs(typed: &TypedModel, batch: &Symbol, window: &Symbol, k: usize) -> (u64, usize) {
    let subs: HashMap<Symbol, TDim> = [(batch.clone(), 1.to_dim()), (window.clone(), k.to_dim())]
        .into_iter()
        .collect();
    let Ok(m) = typed.set_symbols(&subs) else {
        return (u64::MAX, 0);
    };
    let work = || -> TractResult<u64> {
        let mut total = 0u64;
        for n in m.eval_order()? {
            let facts = m.node_input_facts(n)?;
            for (_, count) in m.node(n).op.cost(&facts)? {
                let c = count.to_i64()?;
                total = total.saturating_add(u64::try_from(c).unwrap_or(0));
            }
        }
        Ok(total)
    };
    let largest = || -> TractResult<usize> {
        let mut largest = 0;
        for n in m.eval_order()? {
            for f in m.node_output_facts(n)? {
                // Weights are not per row.
                if f.konst.is_some() {
                    continue;
                }
                if let Some(v) = f.shape.as_concrete() {
                    largest = largest.max(v.iter().product::<usize>() * f.datum_type.size_of());
                }
            }
        }
        Ok(largest)
    };
    (work().unwrap_or(u64::MAX), largest().unwrap_or(0))
}

fn check_output(
    typed: &TypedModel,
    out_name: &str,
    manifest: &PolicyManifest,
    task: &TaskSpec,
) -> Result<(), PolicyError> {
    let slug = task.task.slug();
    let out = typed
        .output_fact(0)
        .map_err(|e| unsupported(format!("{e:#}")))?
        .clone();
    if out.datum_type != f32::datum_type() {
        return Err(mismatch(format!(
            "output `{out_name}` has type {:?}; it must be float32",
            out.datum_type
        )));
    }
    let dims: Vec<Option<i64>> = out.shape.iter().map(|d| d.as_i64()).collect();
    let shown = format!(
        "[{}]",
        out.shape
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let want_act = task.act_dim as i64;
    let h = manifest.horizon as i64;
    let expect = if h == 1 {
        format!("[B, {want_act}] or [B, 1, {want_act}]")
    } else {
        format!("[B, {h}, {want_act}]")
    };
    let last = dims.last().copied().flatten();
    match (dims.len(), last) {
        (2 | 3, Some(a)) if a != want_act => Err(mismatch(format!(
            "output `{out_name}` has last dimension {a} but task {slug} expects {want_act} ({})",
            act_description(task.task)
        ))),
        (2, Some(_)) if h != 1 => Err(mismatch(format!(
            "output `{out_name}` has shape {shown} (one action per row) but the manifest says horizon H = {h}; expected {expect}"
        ))),
        (3, Some(_)) if dims[1].is_some_and(|x| x != h) => Err(mismatch(format!(
            "output `{out_name}` has shape {shown} but the manifest says horizon H = {h}; expected {expect}"
        ))),
        (2 | 3, Some(_)) => Ok(()),
        _ => Err(mismatch(format!(
            "output `{out_name}` has shape {shown}; expected {expect}"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::bucket;

    #[test]
    fn buckets_cover_every_batch_and_waste_at_most_a_third() {
        for b in 1..=5000 {
            let s = bucket(b);
            assert!(s >= b && (s as f64) <= (b as f64) * 1.5 + 1.0, "{b} -> {s}");
            assert!(s >= 2, "{b} -> {s}: no one-row plans");
        }
        assert_eq!(bucket(48), 48);
        assert_eq!(bucket(96), 96);
    }
}
