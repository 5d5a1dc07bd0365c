//! Admission of an ONNX policy: the file is checked before tract allocates
//! anything (declared sizes, external data, data types), its inputs are matched
//! against the manifest and the task, and [`admit`] loads it and runs a test
//! inference, so a graph that cannot run is refused at submission, never at
//! rollout 0 of an evaluation.

use super::OnnxPolicy;
use crate::{act_description, obs_description, PolicyError, IMAGE_SHAPE};
use d3il_protocol::{ObsType, PolicyManifest, TaskSpec, WindowMode};
use tract_onnx::pb;
use tract_onnx::prelude::*;

/// Hard cap on the weights declared by one model; the paper's largest baselines
/// are a few hundred MB. Anything larger is refused before tract allocates it.
pub const MAX_DECLARED_WEIGHT_BYTES: u64 = 2 << 30;

/// Batch size of the test inference run at admission (≥ 2: graphs that fold a
/// symbolic batch into a constant fail only there).
pub const ADMISSION_BATCH: usize = 2;

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Feed {
    Obs,
    Images,
    Noise,
    PrevActions,
}

impl Feed {
    pub(super) fn name(self) -> &'static str {
        match self {
            Feed::Obs => "obs",
            Feed::Images => "images",
            Feed::Noise => "noise",
            Feed::PrevActions => "prev_actions",
        }
    }
}

/// What admission learnt about the model's inputs.
#[derive(Debug, Clone)]
pub(super) struct Signature {
    /// The graph's inputs in order.
    pub feeds: Vec<Feed>,
    /// Non-batch dimensions of `noise`.
    pub noise_dims: Vec<usize>,
    /// `Some(n)` when the file fixes the batch dimension to n.
    pub fixed_batch: Option<usize>,
    /// The window grows from 1 to k at episode start.
    pub grow: bool,
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

/// Loads the policy as an evaluation would and runs the test inference
/// ([`OnnxPolicy::test_inference`]): call it at submission, inside the sandbox,
/// so that a model which cannot run is refused with the reason, never at
/// rollout 0 of its evaluation. (Every evaluation also runs the test inference
/// before its first rollout, through [`crate::Policy::self_test`].)
pub fn admit(
    bytes: &[u8],
    manifest: &PolicyManifest,
    task: &TaskSpec,
    seed: u64,
) -> Result<OnnxPolicy, PolicyError> {
    let p = OnnxPolicy::load(bytes, manifest, task, seed)?;
    p.test_inference()?;
    Ok(p)
}

pub(super) fn mismatch(msg: String) -> PolicyError {
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

/// A tensor's or node's name in a message (ONNX names are optional).
fn shown_name(name: &str) -> &str {
    if name.is_empty() {
        "(unnamed)"
    } else {
        name
    }
}

/// Refuses tensors whose declared size does not match the data they carry, or
/// that live in external files, before tract allocates anything: a hostile file
/// could otherwise declare tens of GiB in a few bytes.
fn check_tensor(t: &pb::TensorProto, what: &str, total: &mut u64) -> Result<(), PolicyError> {
    let name = shown_name(&t.name);
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

/// ONNX operators that draw random numbers inside the graph (`torch.randn` and
/// friends in `forward` export to them). Refused: all randomness comes from the
/// `noise` input, which makes evaluations reproducible bit for bit.
const RANDOM_OPS: [&str; 6] = [
    "RandomNormal",
    "RandomNormalLike",
    "RandomUniform",
    "RandomUniformLike",
    "Multinomial",
    "Bernoulli",
];

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
        if RANDOM_OPS.contains(&n.op_type.as_str())
            && (n.domain.is_empty() || n.domain == "ai.onnx")
        {
            let name = shown_name(&n.name);
            return Err(PolicyError::Unsupported(format!(
                "node `{name}` is a {} operator: it draws from the runtime's own random generator, so the evaluation would not be reproducible; take the random numbers from the `noise` input instead (the evaluator fills it, seeded per rollout and step; docs/export.md shows how to turn it into uniform or categorical samples)",
                n.op_type
            )));
        }
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

/// Parses and checks the file against the manifest and task; returns the
/// parsed model and its input signature.
pub(super) fn inspect(
    bytes: &[u8],
    manifest: &PolicyManifest,
    task: &TaskSpec,
) -> Result<(pb::ModelProto, Signature), PolicyError> {
    let slug = task.task.slug();
    manifest
        .validate_for(task)
        .map_err(|e| PolicyError::BadManifest(e.to_string()))?;
    let grow = manifest.window == WindowMode::Grow && manifest.history > 1;
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
        ObsType::State => "`obs` and optionally `prev_actions` and `noise`",
        ObsType::Image => "`images`, optionally `obs`, `prev_actions` and `noise`",
    };
    let mut feeds = vec![];
    let mut declared = vec![];
    for v in &inputs {
        let feed = match v.name.as_str() {
            "obs" => Feed::Obs,
            "images" if manifest.obs_type == ObsType::Image => Feed::Images,
            "noise" => Feed::Noise,
            "prev_actions" => Feed::PrevActions,
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
        let name = feed.name();
        let expected_rank = match feed {
            Feed::Obs | Feed::PrevActions => 3,
            Feed::Images => 6,
            Feed::Noise => shape.len().max(1),
        };
        if shape.len() != expected_rank {
            let want = match feed {
                Feed::Obs => format!("[B, {k}, {}]", task.obs_dim),
                Feed::PrevActions => format!("[B, {}, {}]", k - 1, task.act_dim),
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
        // A growing window needs a symbolic window dimension (k = 1 never grows).
        let check_window = |want: i64| -> Result<(), PolicyError> {
            match (&shape[1], grow) {
                (Dim::Fixed(v), true) => Err(mismatch(format!(
                    "input `{name}` has a fixed window dimension {v} but the manifest says window `grow`; export the window axis as symbolic (dynamic_axes {{1: \"T\"}}) or set \"window\": \"pad\""
                ))),
                _ => check_fixed(1, want, "history dimension", k_msg()),
            }
        };
        match feed {
            Feed::Obs => {
                check_window(k)?;
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
            Feed::PrevActions => {
                match (&shape[1], grow) {
                    (Dim::Fixed(v), true) => {
                        return Err(mismatch(format!(
                            "input `prev_actions` has a fixed dimension {v} but the manifest says window `grow`; export it as symbolic (dynamic_axes {{1: \"P\"}})"
                        )))
                    }
                    (Dim::Fixed(v), false) if *v != k - 1 => {
                        return Err(mismatch(format!(
                            "input `prev_actions` has dimension 1 = {v} but the manifest says history k = {k}; it carries the last k − 1 = {} actions",
                            k - 1
                        )))
                    }
                    _ => {}
                }
                check_fixed(
                    2,
                    task.act_dim as i64,
                    "last dimension",
                    format!(
                        "task {slug} has {} action components ({})",
                        task.act_dim,
                        act_description(task.task)
                    ),
                )?;
            }
            Feed::Images => {
                check_window(k)?;
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
    Ok((
        proto,
        Signature {
            feeds,
            noise_dims,
            fixed_batch,
            grow,
        },
    ))
}
