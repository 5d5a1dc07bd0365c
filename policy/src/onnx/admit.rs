//! ONNX policies run with tract (docs/submission.md).
//!
//! Inputs (by name): `obs` float32 `[B, k, obs_dim]` (state policies; optional for
//! image policies), `images` float32 `[B, k, 2, 3, 96, 96]` (image policies),
//! optional `noise` float32 `[B, ...]` with fixed non-batch dimensions, filled from
//! standard normal samples of a seeded ChaCha8 stream per (seed, rollout, step).
//! One output: float32 `[B, H, act_dim]` or `[B, act_dim]` (H = 1).
//! The batch dimension may be symbolic or fixed; with a fixed batch n the rows are
//! run n at a time (the last group padded by repeating its last row).

use crate::{
    act_description, obs_description, ActionChunks, Policy, PolicyError, PolicyShape, Query,
    IMAGE_LEN, IMAGE_SHAPE,
};
use d3il_protocol::{ObsType, PolicyManifest, TaskSpec};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, StandardNormal};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Arc;
use tract_onnx::pb;
use tract_onnx::prelude::*;

/// Hard cap on the weights declared by one model; the paper's largest baselines
/// are a few hundred MB. Anything larger is refused before tract allocates it.
pub const MAX_DECLARED_WEIGHT_BYTES: u64 = 2 << 30;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Feed {
    Obs,
    Images,
    Noise,
}

/// A dimension as the file declares it.
#[derive(Debug, Clone, PartialEq, Eq)]
enum Dim {
    Fixed(i64),
    Symbolic(String),
}

impl std::fmt::Display for Dim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Dim::Fixed(v) => write!(f, "{v}"),
            Dim::Symbolic(s) if s.is_empty() => f.write_str("?"),
            Dim::Symbolic(s) => f.write_str(s),
        }
    }
}

struct Norm {
    obs_mean: Option<Vec<f32>>,
    obs_std: Option<Vec<f32>>,
    act_mean: Option<Vec<f32>>,
    act_std: Option<Vec<f32>>,
}

pub struct OnnxPolicy {
    plan: Arc<TypedRunnableModel>,
    shape: PolicyShape,
    feeds: Vec<Feed>,
    /// Non-batch dimensions of `noise`.
    noise_dims: Vec<usize>,
    /// `Some(n)` when the file fixes the batch dimension to n.
    fixed_batch: Option<usize>,
    seed: u64,
    norm: Option<Norm>,
}

impl std::fmt::Debug for OnnxPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxPolicy")
            .field("shape", &self.shape)
            .field("feeds", &self.feeds)
            .field("noise_dims", &self.noise_dims)
            .field("fixed_batch", &self.fixed_batch)
            .finish()
    }
}

fn mismatch(msg: String) -> PolicyError {
    PolicyError::Mismatch(msg)
}

/// Bytes per element of an ONNX data type, `None` for types we refuse.
fn elem_size(data_type: i32) -> Option<u64> {
    use pb::tensor_proto::DataType as D;
    let d = D::try_from(data_type).ok()?;
    Some(match d {
        D::Float | D::Int32 | D::Uint32 => 4,
        D::Uint8 | D::Int8 | D::Bool => 1,
        D::Uint16 | D::Int16 | D::Float16 | D::Bfloat16 => 2,
        D::Int64 | D::Double | D::Uint64 => 8,
        _ => return None,
    })
}

fn human_bytes(b: u64) -> String {
    if b >= 1 << 30 {
        format!("{:.1} GiB", b as f64 / (1u64 << 30) as f64)
    } else if b >= 1 << 20 {
        format!("{:.1} MiB", b as f64 / (1u64 << 20) as f64)
    } else {
        format!("{b} bytes")
    }
}

/// Refuses tensors whose declared size does not match the data they carry, or
/// that live in external files, before tract allocates anything: a hostile file
/// could otherwise declare tens of GiB in a few bytes.
fn check_tensor(t: &pb::TensorProto, what: &str, total: &mut u64) -> Result<(), PolicyError> {
    let name = if t.name.is_empty() {
        "(unnamed)"
    } else {
        &t.name
    };
    if t.data_location == Some(pb::tensor_proto::DataLocation::External as i32)
        || !t.external_data.is_empty()
    {
        return Err(PolicyError::Unsupported(format!(
            "{what} `{name}` keeps its data in an external file; export with all weights embedded in the .onnx file (torch.onnx.export does this below 2 GB)"
        )));
    }
    let size = elem_size(t.data_type).ok_or_else(|| {
        PolicyError::Unsupported(format!(
            "{what} `{name}` has data type {} which policies may not use; use float32/int64/bool tensors",
            t.data_type
        ))
    })?;
    let mut count: u64 = 1;
    for &d in &t.dims {
        if d < 0 {
            return Err(PolicyError::Unparsable(format!(
                "{what} `{name}` has a negative dimension {d}"
            )));
        }
        count = count.checked_mul(d as u64).ok_or_else(|| {
            PolicyError::Unsupported(format!(
                "{what} `{name}` declares an absurd size {:?}",
                t.dims
            ))
        })?;
    }
    let declared = count.saturating_mul(size);
    let dims = t
        .dims
        .iter()
        .map(|d| d.to_string())
        .collect::<Vec<_>>()
        .join("x");
    let actual = if !t.raw_data.is_empty() {
        t.raw_data.len() as u64
    } else {
        let n = t.float_data.len()
            + t.int32_data.len()
            + t.int64_data.len()
            + t.double_data.len()
            + t.uint64_data.len()
            + t.string_data.len();
        (n as u64).saturating_mul(size)
    };
    if actual != declared {
        return Err(PolicyError::Unparsable(format!(
            "{what} `{name}` declares shape {dims} ({}) but holds {}",
            human_bytes(declared),
            human_bytes(actual)
        )));
    }
    *total = total.saturating_add(declared);
    if *total > MAX_DECLARED_WEIGHT_BYTES {
        return Err(PolicyError::Unsupported(format!(
            "the model's weights exceed {} (at {what} `{name}`); policies must be smaller",
            human_bytes(MAX_DECLARED_WEIGHT_BYTES)
        )));
    }
    Ok(())
}

fn check_graph(g: &pb::GraphProto, total: &mut u64, depth: usize) -> Result<(), PolicyError> {
    if depth > 8 {
        return Err(PolicyError::Unsupported(
            "subgraphs are nested more than 8 deep".into(),
        ));
    }
    if !g.sparse_initializer.is_empty() {
        return Err(PolicyError::Unsupported(
            "sparse initializers are not supported; export dense weights".into(),
        ));
    }
    for t in &g.initializer {
        check_tensor(t, "initializer", total)?;
    }
    for n in &g.node {
        for a in &n.attribute {
            if let Some(t) = &a.t {
                check_tensor(t, "constant", total)?;
            }
            for t in &a.tensors {
                check_tensor(t, "constant", total)?;
            }
            if let Some(sub) = &a.g {
                check_graph(sub, total, depth + 1)?;
            }
            for sub in &a.graphs {
                check_graph(sub, total, depth + 1)?;
            }
        }
    }
    Ok(())
}

/// Declared shape of a graph input, `None` when the file gives no shape.
fn declared_shape(v: &pb::ValueInfoProto) -> Result<(i32, Option<Vec<Dim>>), PolicyError> {
    use pb::tensor_shape_proto::dimension::Value;
    let Some(pb::type_proto::Value::TensorType(t)) =
        v.r#type.as_ref().and_then(|t| t.value.as_ref())
    else {
        return Err(PolicyError::Unsupported(format!(
            "input `{}` is not a tensor",
            v.name
        )));
    };
    let shape = t.shape.as_ref().map(|s| {
        s.dim
            .iter()
            .map(|d| match &d.value {
                Some(Value::DimValue(x)) => Dim::Fixed(*x),
                Some(Value::DimParam(p)) => Dim::Symbolic(p.clone()),
                None => Dim::Symbolic(String::new()),
            })
            .collect()
    });
    Ok((t.elem_type, shape))
}

fn fmt_shape(s: &[Dim]) -> String {
    format!(
        "[{}]",
        s.iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    )
}

impl OnnxPolicy {
    /// Load and validate a policy from the bytes of an .onnx file and its manifest
    /// against the task's dimensions. `seed` drives the `noise` input.
    pub fn load(
        bytes: &[u8],
        manifest: &PolicyManifest,
        task: &TaskSpec,
        seed: u64,
    ) -> Result<Self, PolicyError> {
        // tract panics on a few malformed inputs (unimplemented data types);
        // a submission must never take the evaluator down with it.
        match catch_unwind(AssertUnwindSafe(|| {
            Self::load_inner(bytes, manifest, task, seed)
        })) {
            Ok(r) => r,
            Err(p) => {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_else(|| "unknown panic".into());
                Err(PolicyError::Unsupported(format!(
                    "the ONNX runtime could not handle this model ({msg})"
                )))
            }
        }
    }

    fn load_inner(
        bytes: &[u8],
        manifest: &PolicyManifest,
        task: &TaskSpec,
        seed: u64,
    ) -> Result<Self, PolicyError> {
        let slug = task.task.slug();
        if manifest.task != task.task {
            return Err(PolicyError::BadManifest(format!(
                "it is for task {} but is being evaluated on {slug}",
                manifest.task
            )));
        }
        if manifest.history == 0 || manifest.horizon == 0 {
            return Err(PolicyError::BadManifest(format!(
                "history (k = {}) and horizon (H = {}) must be at least 1",
                manifest.history, manifest.horizon
            )));
        }
        if manifest.execute == 0 || manifest.execute > manifest.horizon {
            return Err(PolicyError::BadManifest(format!(
                "execute (E = {}) must be between 1 and the horizon H = {}",
                manifest.execute, manifest.horizon
            )));
        }
        let norm = Self::check_norm(manifest, task)?;

        let onnx = tract_onnx::onnx();
        let proto = onnx
            .proto_model_for_read(&mut &bytes[..])
            .map_err(|e| PolicyError::Unparsable(format!("{e:#}")))?;
        let graph = proto
            .graph
            .as_ref()
            .ok_or_else(|| PolicyError::Unparsable("the file contains no graph".into()))?;
        let mut total = 0;
        check_graph(graph, &mut total, 0)?;

        // Graph inputs that are not initializers (older exporters list both).
        let init_names: std::collections::HashSet<&str> =
            graph.initializer.iter().map(|t| t.name.as_str()).collect();
        let inputs: Vec<&pb::ValueInfoProto> = graph
            .input
            .iter()
            .filter(|v| !init_names.contains(v.name.as_str()))
            .collect();
        let allowed = match manifest.obs_type {
            ObsType::State => "`obs` and optionally `noise`",
            ObsType::Image => "`images`, optionally `obs` and `noise`",
        };
        let mut feeds = vec![];
        let mut declared = vec![];
        for v in &inputs {
            let feed = match v.name.as_str() {
                "obs" => Feed::Obs,
                "images" if manifest.obs_type == ObsType::Image => Feed::Images,
                "noise" => Feed::Noise,
                other => {
                    return Err(mismatch(format!(
                        "the model has an input `{other}`; a {} policy has inputs {allowed}",
                        manifest.obs_type
                    )))
                }
            };
            let (elem, shape) = declared_shape(v)?;
            if elem != pb::tensor_proto::DataType::Float as i32 {
                return Err(mismatch(format!(
                    "input `{}` has ONNX element type {elem}; it must be float32 (type 1)",
                    v.name
                )));
            }
            let shape = shape.ok_or_else(|| {
                mismatch(format!(
                    "input `{}` declares no shape; export with named dimensions (see docs/submission.md)",
                    v.name
                ))
            })?;
            feeds.push(feed);
            declared.push(shape);
        }
        match manifest.obs_type {
            ObsType::State if !feeds.contains(&Feed::Obs) => {
                return Err(mismatch(
                    "the model has no input named `obs`; a state policy takes `obs` [B, k, obs_dim]"
                        .into(),
                ))
            }
            ObsType::Image if !feeds.contains(&Feed::Images) => {
                return Err(mismatch(
                    "the model has no input named `images`; an image policy takes `images` [B, k, 2, 3, 96, 96]"
                        .into(),
                ))
            }
            _ => {}
        }

        // Batch dimension: all inputs must agree on it.
        let k = manifest.history as i64;
        let mut batch: Option<Dim> = None;
        let mut noise_dims = vec![];
        for (feed, shape) in feeds.iter().zip(&declared) {
            let name = match feed {
                Feed::Obs => "obs",
                Feed::Images => "images",
                Feed::Noise => "noise",
            };
            let expected_rank = match feed {
                Feed::Obs => 3,
                Feed::Images => 6,
                Feed::Noise => shape.len().max(1),
            };
            if shape.len() != expected_rank {
                let want = match feed {
                    Feed::Obs => format!("[B, {k}, {}]", task.obs_dim),
                    _ => format!("[B, {k}, 2, 3, 96, 96]"),
                };
                return Err(mismatch(format!(
                    "input `{name}` has shape {} but task {slug} expects {want}",
                    fmt_shape(shape)
                )));
            }
            match (&batch, &shape[0]) {
                (None, d) => batch = Some(d.clone()),
                (Some(Dim::Fixed(a)), Dim::Fixed(b)) if a != b => {
                    return Err(mismatch(format!(
                        "input `{name}` has batch dimension {b} but another input has {a}; all inputs share the batch dimension"
                    )))
                }
                _ => {}
            }
            // `expected` completes "... but <expected>".
            let check_fixed = |i: usize, want: i64, what: &str, expected: String| match &shape[i] {
                Dim::Fixed(v) if *v != want => Err(mismatch(format!(
                    "input `{name}` has {what} {v} but {expected}"
                ))),
                _ => Ok(()),
            };
            let k_msg = || format!("the manifest says history k = {k}");
            match feed {
                Feed::Obs => {
                    check_fixed(1, k, "history dimension", k_msg())?;
                    check_fixed(
                        2,
                        task.obs_dim as i64,
                        "last dimension",
                        format!(
                            "task {slug} expects {} ({})",
                            task.obs_dim,
                            obs_description(task.task)
                        ),
                    )?;
                }
                Feed::Images => {
                    check_fixed(1, k, "history dimension", k_msg())?;
                    for (i, &d) in IMAGE_SHAPE.iter().enumerate() {
                        check_fixed(
                            i + 2,
                            d as i64,
                            &format!("dimension {}", i + 2),
                            format!("image inputs are [B, {k}, 2, 3, 96, 96]"),
                        )?;
                    }
                }
                Feed::Noise => {
                    for (i, d) in shape.iter().enumerate().skip(1) {
                        match d {
                            Dim::Fixed(v) if *v > 0 && *v <= 1 << 20 => noise_dims.push(*v as usize),
                            _ => {
                                return Err(mismatch(format!(
                                    "input `noise` has shape {}; its dimension {i} must be a fixed positive size (only the batch dimension may be symbolic)",
                                    fmt_shape(shape)
                                )))
                            }
                        }
                    }
                }
            }
        }
        let fixed_batch = match batch {
            Some(Dim::Fixed(n)) if n >= 1 => Some(n as usize),
            Some(Dim::Fixed(n)) => {
                return Err(mismatch(format!(
                    "the inputs have batch dimension {n}; use a symbolic batch dimension (dynamic_axes) or 1"
                )))
            }
            _ => None,
        };
        if fixed_batch.is_some_and(|n| n > 4096) {
            return Err(mismatch(
                "the fixed batch dimension is larger than 4096; export with a dynamic batch axis"
                    .into(),
            ));
        }

        let mut model = onnx
            .model_for_proto_model(&proto)
            .map_err(|e| PolicyError::Unsupported(format!("{e:#}")))?;
        let b_dim: TDim = match fixed_batch {
            Some(n) => n.to_dim(),
            None => model.symbols.sym("B").into(),
        };
        for (i, (feed, _)) in feeds.iter().zip(&declared).enumerate() {
            let mut dims: Vec<TDim> = vec![b_dim.clone()];
            match feed {
                Feed::Obs => {
                    dims.push(manifest.history.to_dim());
                    dims.push(task.obs_dim.to_dim());
                }
                Feed::Images => {
                    dims.push(manifest.history.to_dim());
                    dims.extend(IMAGE_SHAPE.iter().map(|d| d.to_dim()));
                }
                Feed::Noise => dims.extend(noise_dims.iter().map(|d| d.to_dim())),
            }
            // Input order in tract follows the graph's non-initializer inputs.
            model
                .set_input_fact(i, f32::fact(dims).into())
                .map_err(|e| PolicyError::Unsupported(format!("{e:#}")))?;
        }
        if model.output_outlets().map(|o| o.len()).unwrap_or(0) != 1 {
            return Err(mismatch(format!(
                "the model has {} outputs; it must have exactly one, the actions [B, H, act_dim] or [B, act_dim]",
                model.output_outlets().map(|o| o.len()).unwrap_or(0)
            )));
        }
        let typed = model.into_optimized().map_err(|e| {
            PolicyError::Unsupported(format!(
                "tract could not analyse the graph with the declared input shapes: {e:#}"
            ))
        })?;
        let out = typed
            .output_fact(0)
            .map_err(|e| PolicyError::Unsupported(format!("{e:#}")))?
            .clone();
        let out_name = graph
            .output
            .first()
            .map(|o| o.name.clone())
            .unwrap_or_else(|| "output".into());
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
            (2 | 3, Some(a)) if a != want_act => {
                return Err(mismatch(format!(
                    "output `{out_name}` has last dimension {a} but task {slug} expects {want_act} ({})",
                    act_description(task.task)
                )))
            }
            (2, Some(_)) if h != 1 => {
                return Err(mismatch(format!(
                    "output `{out_name}` has shape {shown} (one action per row) but the manifest says horizon H = {h}; expected {expect}"
                )))
            }
            (3, Some(_)) if dims[1].is_some_and(|x| x != h) => {
                return Err(mismatch(format!(
                    "output `{out_name}` has shape {shown} but the manifest says horizon H = {h}; expected {expect}"
                )))
            }
            (2 | 3, Some(_)) => {}
            _ => {
                return Err(mismatch(format!(
                    "output `{out_name}` has shape {shown}; expected {expect}"
                )))
            }
        }
        let plan = typed
            .into_runnable()
            .map_err(|e| PolicyError::Unsupported(format!("{e:#}")))?;
        Ok(OnnxPolicy {
            plan,
            shape: PolicyShape {
                history: manifest.history,
                horizon: manifest.horizon,
                execute: manifest.execute,
                obs_dim: task.obs_dim,
                act_dim: task.act_dim,
                obs_type: manifest.obs_type,
            },
            feeds,
            noise_dims,
            fixed_batch,
            seed,
            norm,
        })
    }

    fn check_norm(manifest: &PolicyManifest, task: &TaskSpec) -> Result<Option<Norm>, PolicyError> {
        let Some(n) = &manifest.normalisation else {
            return Ok(None);
        };
        let check = |v: &Option<Vec<f32>>, len: usize, what: &str| -> Result<(), PolicyError> {
            if let Some(v) = v {
                if v.len() != len {
                    return Err(PolicyError::BadManifest(format!(
                        "normalisation.{what} has {} entries but task {} needs {len}",
                        v.len(),
                        task.task
                    )));
                }
                if v.iter().any(|x| !x.is_finite()) {
                    return Err(PolicyError::BadManifest(format!(
                        "normalisation.{what} contains a non-finite value"
                    )));
                }
                if what.ends_with("std") && v.iter().any(|x| *x <= 0.0) {
                    return Err(PolicyError::BadManifest(format!(
                        "normalisation.{what} must be positive everywhere"
                    )));
                }
            }
            Ok(())
        };
        check(&n.obs_mean, task.obs_dim, "obs_mean")?;
        check(&n.obs_std, task.obs_dim, "obs_std")?;
        check(&n.act_mean, task.act_dim, "act_mean")?;
        check(&n.act_std, task.act_dim, "act_std")?;
        Ok(Some(Norm {
            obs_mean: n.obs_mean.clone(),
            obs_std: n.obs_std.clone(),
            act_mean: n.act_mean.clone(),
            act_std: n.act_std.clone(),
        }))
    }

    /// Standard normal noise for one row, a pure function of (seed, rollout, step)
    /// so results do not depend on batch composition or fixed-batch chunking.
    fn noise_row(&self, rollout: u64, step: u64, out: &mut Vec<f32>) {
        let mut key = [0u8; 32];
        key[0..8].copy_from_slice(&self.seed.to_le_bytes());
        key[8..16].copy_from_slice(&rollout.to_le_bytes());
        key[16..24].copy_from_slice(&step.to_le_bytes());
        key[24..32].copy_from_slice(b"d3ilnois");
        let mut rng = ChaCha8Rng::from_seed(key);
        let n: usize = self.noise_dims.iter().product();
        out.extend((0..n).map(|_| {
            let v: f32 = StandardNormal.sample(&mut rng);
            v
        }));
    }

    /// Run rows `rows` (indices into the query) as one model call of `n` rows
    /// (n ≥ rows.len(); extra rows repeat the last one).
    fn run_rows(
        &self,
        q: &Query<'_>,
        rows: std::ops::Range<usize>,
        n: usize,
        out: &mut Vec<f32>,
    ) -> Result<(), PolicyError> {
        let s = &self.shape;
        let row_of = |i: usize| (rows.start + i).min(rows.end - 1);
        let err = |e: String| PolicyError::Inference {
            rollout: q.rollout_ids[rows.start],
            step: q.steps[rows.start],
            message: e,
        };
        let mut inputs: TVec<TValue> = tvec![];
        for feed in &self.feeds {
            let t = match feed {
                Feed::Obs => {
                    let w = s.history * s.obs_dim;
                    let mut v = Vec::with_capacity(n * w);
                    for i in 0..n {
                        let r = row_of(i);
                        let src = &q.obs[r * w..(r + 1) * w];
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
                    Tensor::from_shape(&[n, s.history, s.obs_dim], &v)
                }
                Feed::Images => {
                    let w = s.history * IMAGE_LEN;
                    let images = q.images.unwrap_or(&[]);
                    let mut v = Vec::with_capacity(n * w);
                    for i in 0..n {
                        let r = row_of(i);
                        v.extend_from_slice(&images[r * w..(r + 1) * w]);
                    }
                    let mut shape = vec![n, s.history];
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
                    shape.extend_from_slice(&self.noise_dims);
                    Tensor::from_shape(&shape, &v)
                }
            }
            .map_err(|e| err(format!("{e:#}")))?;
            inputs.push(t.into_tvalue());
        }
        let result = catch_unwind(AssertUnwindSafe(|| self.plan.run(inputs)))
            .map_err(|_| err("the ONNX runtime panicked".into()))?
            .map_err(|e| err(format!("{e:#}")))?;
        let Some(first) = result.first() else {
            return Err(err("the model returned no output".into()));
        };
        let view = first
            .to_plain_array_view::<f32>()
            .map_err(|e| err(format!("{e:#}")))?;
        let per_row = s.horizon * s.act_dim;
        let shape = view.shape().to_vec();
        let ok = match shape.len() {
            2 => shape == [n, s.act_dim] && s.horizon == 1,
            3 => shape == [n, s.horizon, s.act_dim],
            _ => false,
        };
        if !ok {
            return Err(PolicyError::WrongShape {
                got: format!("actions {shape:?}"),
                expected: format!("[{n}, {}, {}]", s.horizon, s.act_dim),
                batch: n,
                rollout: q.rollout_ids[rows.start],
                step: q.steps[rows.start],
            });
        }
        let flat: Vec<f32> = view.iter().copied().collect();
        let real = rows.end - rows.start;
        out.extend_from_slice(&flat[..real * per_row]);
        Ok(())
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
        let b = q.batch();
        let s = self.shape;
        let mut data = Vec::with_capacity(b * s.horizon * s.act_dim);
        if b > 0 {
            match self.fixed_batch {
                None => self.run_rows(q, 0..b, b, &mut data)?,
                Some(n) => {
                    let mut start = 0;
                    while start < b {
                        let end = (start + n).min(b);
                        self.run_rows(q, start..end, n, &mut data)?;
                        start = end;
                    }
                }
            }
        }
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
            batch: b,
            horizon: s.horizon,
            act_dim: s.act_dim,
            data,
        })
    }
}
