//! Our own kernels for patterns that tract 0.23 runs through slow generic
//! paths, swapped into each optimised plan ([`speed_up`]):
//!
//! - `Cast<f32>(x > c)` (any comparison of an f32 tensor with a scalar
//!   constant, turned into 0/1): a relu's derivative in hand-written
//!   gradients (IBC). tract compares through an ndarray broadcast and then
//!   casts the booleans; here one pass writes 0.0 / 1.0, and when the mask
//!   is multiplied with a tensor, one pass writes the product.
//! - Element-wise `+ − × ÷ max min` of two f32 tensors broadcast along a
//!   middle axis (`[B, S, d] + [B, 1, d]`), which tract's fast by-scalar and
//!   unicast kernels do not take: here a loop over the outer indices with a
//!   contiguous inner row.
//! - Softmax over the last axis of short f32 rows (attention over 10 or 12
//!   tokens): tract runs its SIMD kernels once per row (with an aligned
//!   scratch copy each time when the length is not a multiple of 4); here its
//!   exp kernel runs once over the whole tensor.
//!
//! All but the softmax give exactly the values tract gives (the same IEEE
//! operation per element); the softmax gives tract's exponentials, summed per
//! row in another order (well within the agreement with onnxruntime the agent
//! fixture tests check, `tract_matches_onnxruntime_on_recorded_inputs`).
//! Tensors that are not plain and contiguous go back to tract's own op.

use tract_onnx::prelude::tract_linalg::routines::Func;
use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::*;
use tract_onnx::tract_core::ops::binary::{OptBinByScalar, OptBinUnicast, TypedBinOp};
use tract_onnx::tract_core::ops::cast::Cast;
use tract_onnx::tract_core::ops::logic::{CompEq, CompGT, CompGTE, CompLT, CompLTE, CompNE};
use tract_onnx::tract_core::ops::math::{Add, Div, Max, Min, Mul, Sub};
use tract_onnx::tract_core::ops::nn::{Softmax, SoftmaxKind};

/// Swaps the three patterns for our kernels in an optimised model.
pub(super) fn speed_up(model: &mut TypedModel) -> TractResult<()> {
    let ids: Vec<usize> = model.eval_order()?;
    for id in ids {
        let node = model.node(id).clone();
        let patch = if let Some(cast) = node.op_as::<Cast>() {
            cmp_cast(model, &node, cast)?
        } else if let Some(p) = mask_mul(model, &node)? {
            Some(p)
        } else if let Some(bin) = node.op_as::<TypedBinOp>() {
            broadcast_bin(model, &node, bin)?
        } else if let Some(sm) = node.op_as::<Softmax>() {
            softmax(model, &node, sm)?
        } else {
            None
        };
        if let Some(p) = patch {
            p.apply(model)?;
        }
    }
    Ok(())
}

fn is_f32(model: &TypedModel, o: OutletId) -> TractResult<bool> {
    Ok(model.outlet_fact(o)?.datum_type == f32::datum_type())
}

fn concrete(model: &TypedModel, o: OutletId) -> TractResult<Option<TVec<usize>>> {
    Ok(model.outlet_fact(o)?.shape.as_concrete().map(|s| s.into()))
}

fn natural(t: &Tensor) -> bool {
    t.strides() == &*Tensor::natural_strides(t.shape())
}

// ------------------------------------------------------------ comparisons --

#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
enum Cmp {
    Gt,
    Ge,
    Lt,
    Le,
    Eq,
    Ne,
}

impl Cmp {
    /// The comparison with its operands swapped (`c < x` is `x > c`).
    fn flip(self) -> Cmp {
        match self {
            Cmp::Gt => Cmp::Lt,
            Cmp::Ge => Cmp::Le,
            Cmp::Lt => Cmp::Gt,
            Cmp::Le => Cmp::Ge,
            other => other,
        }
    }
}

/// `(x cmp c) as f32` for an f32 tensor `x` and a scalar `c`.
#[derive(Debug, Clone, Hash, PartialEq, Eq)]
struct CmpToF32 {
    cmp: Cmp,
    c_bits: u32,
}

impl Op for CmpToF32 {
    fn name(&self) -> StaticName {
        "D3ilCmpToF32".into()
    }
    op_as_typed_op!();
}

impl EvalOp for CmpToF32 {
    op_out_of_plan!();

    fn eval(&self, _ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = args_1!(inputs);
        let c = f32::from_bits(self.c_bits);
        // The mask overwrites x (a copy of it when x is read elsewhere too).
        let mut out = if natural(&x) {
            x.into_tensor()
        } else {
            let v = x.to_plain_array_view::<f32>()?;
            Tensor::from_shape(x.shape(), &v.iter().copied().collect::<Vec<f32>>())?
        };
        {
            let mut ov = out.try_as_plain_ram_mut()?;
            let os = ov.as_slice_mut::<f32>()?;
            macro_rules! run {
                ($op:tt) => {
                    os.iter_mut().for_each(|v| *v = if *v $op c { 1.0 } else { 0.0 })
                };
            }
            match self.cmp {
                Cmp::Gt => run!(>),
                Cmp::Ge => run!(>=),
                Cmp::Lt => run!(<),
                Cmp::Le => run!(<=),
                Cmp::Eq => run!(==),
                Cmp::Ne => run!(!=),
            }
        }
        Ok(tvec!(out.into_tvalue()))
    }
}

impl TypedOp for CmpToF32 {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec!(f32::fact(inputs[0].shape.clone())))
    }
    as_op!();
}

fn cmp_of(bin: &TypedBinOp) -> Option<Cmp> {
    let m = &bin.0;
    Some(if m.is::<CompGT>() {
        Cmp::Gt
    } else if m.is::<CompGTE>() {
        Cmp::Ge
    } else if m.is::<CompLT>() {
        Cmp::Lt
    } else if m.is::<CompLTE>() {
        Cmp::Le
    } else if m.is::<CompEq>() {
        Cmp::Eq
    } else if m.is::<CompNE>() {
        Cmp::Ne
    } else {
        return None;
    })
}

/// `Cast<f32>(Comparison(x, scalar))` with an f32 `x` → [`CmpToF32`].
fn cmp_cast(
    model: &TypedModel,
    node: &TypedNode,
    cast: &Cast,
) -> TractResult<Option<TypedModelPatch>> {
    if cast.to != f32::datum_type() {
        return Ok(None);
    }
    let prev = model.node(node.inputs[0].node);
    let Some(bin) = prev.op_as::<TypedBinOp>() else {
        return Ok(None);
    };
    let Some(cmp) = cmp_of(bin) else {
        return Ok(None);
    };
    let out_shape = concrete(model, node.id.into())?;
    for (var, konst, cmp) in [(0, 1, cmp), (1, 0, cmp.flip())] {
        let (x, k) = (prev.inputs[var], prev.inputs[konst]);
        let kf = model.outlet_fact(k)?;
        let Some(c) = kf.konst.as_ref() else {
            continue;
        };
        if c.datum_type() != f32::datum_type() || c.len() != 1 || !is_f32(model, x)? {
            continue;
        }
        // The comparison must not broadcast x: its output has x's shape.
        if out_shape.is_none() || concrete(model, x)? != out_shape {
            continue;
        }
        let c = c.cast_to_scalar::<f32>()?;
        let mut patch = TypedModelPatch::default();
        let tap = patch.tap_model(model, x)?;
        let wire = patch.wire_node(
            &node.name,
            CmpToF32 {
                cmp,
                c_bits: c.to_bits(),
            },
            &[tap],
        )?;
        patch.shunt_outside(model, node.id.into(), wire[0])?;
        return Ok(Some(patch));
    }
    Ok(None)
}

// ------------------------------------------------ broadcast element-wise --

#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
enum Bin {
    Add,
    Sub,
    Mul,
    Div,
    Max,
    Min,
}

impl Bin {
    fn of(bin: &TypedBinOp) -> Option<Bin> {
        let m = &bin.0;
        Some(if m.is::<Add>() {
            Bin::Add
        } else if m.is::<Sub>() {
            Bin::Sub
        } else if m.is::<Mul>() {
            Bin::Mul
        } else if m.is::<Div>() {
            Bin::Div
        } else if m.is::<Max>() {
            Bin::Max
        } else if m.is::<Min>() {
            Bin::Min
        } else {
            return None;
        })
    }

    /// tract's own op, for inputs this kernel does not take.
    fn tract(self) -> TypedBinOp {
        let mini: Box<dyn tract_onnx::tract_core::ops::binary::BinMiniOp> = match self {
            Bin::Add => Box::new(Add),
            Bin::Sub => Box::new(Sub),
            Bin::Mul => Box::new(Mul),
            Bin::Div => Box::new(Div),
            Bin::Max => Box::new(Max),
            Bin::Min => Box::new(Min),
        };
        TypedBinOp(mini, None)
    }
}

/// `a op b` for f32 tensors of equal rank with numpy broadcasting.
#[derive(Debug, Clone, Hash, PartialEq, Eq)]
struct BroadcastBin {
    op: Bin,
}

impl Op for BroadcastBin {
    fn name(&self) -> StaticName {
        format!("D3ilBroadcast{:?}", self.op).into()
    }
    op_as_typed_op!();
}

/// `out[o] = f(a[o], b[o])` over the rows of the output's last axis, each
/// input read with stride 1 or 0 (broadcast) along each axis.
fn broadcast_rows(
    a: &[f32],
    a_shape: &[usize],
    b: &[f32],
    b_shape: &[usize],
    out: &mut [f32],
    out_shape: &[usize],
    f: impl Fn(f32, f32) -> f32 + Copy,
) {
    let rank = out_shape.len();
    let strides = |shape: &[usize]| -> Vec<usize> {
        let mut s = vec![0; rank];
        let mut acc = 1;
        for i in (0..rank).rev() {
            s[i] = if shape[i] == 1 { 0 } else { acc };
            acc *= shape[i];
        }
        s
    };
    let (sa, sb) = (strides(a_shape), strides(b_shape));
    let n = out_shape[rank - 1];
    let (ia, ib) = (sa[rank - 1], sb[rank - 1]);
    let mut idx = vec![0usize; rank - 1];
    let (mut oa, mut ob) = (0usize, 0usize);
    for row in out.chunks_exact_mut(n) {
        match (ia, ib) {
            (1, 1) => {
                for ((o, &x), &y) in row.iter_mut().zip(&a[oa..oa + n]).zip(&b[ob..ob + n]) {
                    *o = f(x, y);
                }
            }
            (1, 0) => {
                let y = b[ob];
                for (o, &x) in row.iter_mut().zip(&a[oa..oa + n]) {
                    *o = f(x, y);
                }
            }
            (0, 1) => {
                let x = a[oa];
                for (o, &y) in row.iter_mut().zip(&b[ob..ob + n]) {
                    *o = f(x, y);
                }
            }
            _ => {
                let v = f(a[oa], b[ob]);
                row.iter_mut().for_each(|o| *o = v);
            }
        }
        // Next row: odometer over the outer axes.
        for ax in (0..rank - 1).rev() {
            idx[ax] += 1;
            oa += sa[ax];
            ob += sb[ax];
            if idx[ax] < out_shape[ax] {
                break;
            }
            oa -= sa[ax] * idx[ax];
            ob -= sb[ax] * idx[ax];
            idx[ax] = 0;
        }
    }
}

/// `o[i] = f(o[i], b[i])` in place, `o` having the full `shape` and `b`
/// broadcast to it (stride 1 or 0 along each axis).
fn broadcast_rows_in_place(
    o: &mut [f32],
    b: &[f32],
    b_shape: &[usize],
    shape: &[usize],
    f: impl Fn(f32, f32) -> f32 + Copy,
) {
    let rank = shape.len();
    let mut sb = vec![0; rank];
    let mut acc = 1;
    for i in (0..rank).rev() {
        sb[i] = if b_shape[i] == 1 { 0 } else { acc };
        acc *= b_shape[i];
    }
    let n = shape[rank - 1];
    let ib = sb[rank - 1];
    let mut idx = vec![0usize; rank - 1];
    let mut ob = 0usize;
    for row in o.chunks_exact_mut(n) {
        if ib == 1 {
            for (x, &y) in row.iter_mut().zip(&b[ob..ob + n]) {
                *x = f(*x, y);
            }
        } else {
            let y = b[ob];
            row.iter_mut().for_each(|x| *x = f(*x, y));
        }
        for ax in (0..rank - 1).rev() {
            idx[ax] += 1;
            ob += sb[ax];
            if idx[ax] < shape[ax] {
                break;
            }
            ob -= sb[ax] * idx[ax];
            idx[ax] = 0;
        }
    }
}

/// Whether `t` is an f32 tensor, plain and contiguous, of rank ≥ 1 with no
/// empty axis: what our kernels take.
fn plain_f32(t: &Tensor) -> bool {
    t.datum_type() == f32::datum_type()
        && natural(t)
        && t.rank() > 0
        && t.shape().iter().all(|&d| d > 0)
}

/// Whether `small` broadcasts to `full` (equal rank, each axis equal or 1).
fn broadcasts_to(small: &[usize], full: &[usize]) -> bool {
    small.len() == full.len() && small.iter().zip(full).all(|(a, b)| a == b || *a == 1)
}

impl EvalOp for BroadcastBin {
    op_out_of_plan!();

    fn eval(&self, ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let (a, b) = (&inputs[0], &inputs[1]);
        let shape = tract_onnx::tract_core::broadcast::multi_broadcast(&[a.shape(), b.shape()])?;
        if !(plain_f32(a) && plain_f32(b) && a.rank() == b.rank()) {
            return self.op.tract().eval(ctx, inputs);
        }
        let commutes = matches!(self.op, Bin::Add | Bin::Mul | Bin::Max | Bin::Min);
        // The output overwrites the input that has its shape: a, or b when
        // the operation commutes (the same bits either way round).
        let (a, b) = args_2!(inputs);
        let (full, other) = if *a.shape() == *shape {
            (a, b)
        } else if commutes && *b.shape() == *shape {
            (b, a)
        } else {
            let mut out = Tensor::zero::<f32>(&shape)?;
            {
                let av = a.try_as_plain_ram()?;
                let bv = b.try_as_plain_ram()?;
                let mut ov = out.try_as_plain_ram_mut()?;
                let (xs, ys, os) = (
                    av.as_slice::<f32>()?,
                    bv.as_slice::<f32>()?,
                    ov.as_slice_mut::<f32>()?,
                );
                let (sa, sb) = (a.shape(), b.shape());
                match self.op {
                    Bin::Add => broadcast_rows(xs, sa, ys, sb, os, &shape, |x, y| x + y),
                    Bin::Sub => broadcast_rows(xs, sa, ys, sb, os, &shape, |x, y| x - y),
                    Bin::Mul => broadcast_rows(xs, sa, ys, sb, os, &shape, |x, y| x * y),
                    Bin::Div => broadcast_rows(xs, sa, ys, sb, os, &shape, |x, y| x / y),
                    // tract's Max / Min: `if a > b { a } else { b }` and the converse.
                    Bin::Max => {
                        broadcast_rows(xs, sa, ys, sb, os, &shape, |x, y| if x > y { x } else { y })
                    }
                    Bin::Min => {
                        broadcast_rows(xs, sa, ys, sb, os, &shape, |x, y| if x < y { x } else { y })
                    }
                }
            }
            return Ok(tvec!(out.into_tvalue()));
        };
        let mut out = full.into_tensor();
        {
            let ov_b = other.try_as_plain_ram()?;
            let ys = ov_b.as_slice::<f32>()?;
            let mut ov = out.try_as_plain_ram_mut()?;
            let os = ov.as_slice_mut::<f32>()?;
            let sb = other.shape();
            match self.op {
                Bin::Add => broadcast_rows_in_place(os, ys, sb, &shape, |x, y| x + y),
                Bin::Mul => broadcast_rows_in_place(os, ys, sb, &shape, |x, y| x * y),
                Bin::Sub => broadcast_rows_in_place(os, ys, sb, &shape, |x, y| x - y),
                Bin::Div => broadcast_rows_in_place(os, ys, sb, &shape, |x, y| x / y),
                Bin::Max => {
                    broadcast_rows_in_place(os, ys, sb, &shape, |x, y| if x > y { x } else { y })
                }
                Bin::Min => {
                    broadcast_rows_in_place(os, ys, sb, &shape, |x, y| if x < y { x } else { y })
                }
            }
        }
        Ok(tvec!(out.into_tvalue()))
    }
}

impl TypedOp for BroadcastBin {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        self.op.tract().output_facts(inputs)
    }
    as_op!();
}

/// A generic f32 `TypedBinOp` left by the optimiser (its fast kernels did
/// not apply) → [`BroadcastBin`].
fn broadcast_bin(
    model: &TypedModel,
    node: &TypedNode,
    bin: &TypedBinOp,
) -> TractResult<Option<TypedModelPatch>> {
    let Some(op) = Bin::of(bin) else {
        return Ok(None);
    };
    if bin.1.is_some_and(|dt| dt != f32::datum_type())
        || !is_f32(model, node.inputs[0])?
        || !is_f32(model, node.inputs[1])?
        || !is_f32(model, node.id.into())?
    {
        return Ok(None);
    }
    let (Some(a), Some(b)) = (
        concrete(model, node.inputs[0])?,
        concrete(model, node.inputs[1])?,
    ) else {
        return Ok(None);
    };
    if a.len() != b.len() || a.is_empty() {
        return Ok(None);
    }
    Ok(Some(TypedModelPatch::replace_single_op(
        model,
        node,
        &node.inputs,
        BroadcastBin { op },
    )?))
}

// ---------------------------------------------------------- masked product --

/// `(x cmp c) as f32 × y`, i.e. `y` where the comparison holds and `0 × y`
/// elsewhere (the same bits as the product with 1.0 or 0.0), with `y`
/// broadcast to `x`'s shape: a relu's derivative applied to a gradient.
#[derive(Debug, Clone, Hash, PartialEq, Eq)]
struct MaskMul {
    cmp: Cmp,
    c_bits: u32,
}

impl Op for MaskMul {
    fn name(&self) -> StaticName {
        "D3ilMaskMul".into()
    }
    op_as_typed_op!();
}

impl EvalOp for MaskMul {
    op_out_of_plan!();

    fn eval(&self, ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let (x, y) = (&inputs[0], &inputs[1]);
        if !(plain_f32(x) && plain_f32(y) && broadcasts_to(y.shape(), x.shape())) {
            // The two steps, by tract and by our comparison.
            let cmp = CmpToF32 {
                cmp: self.cmp,
                c_bits: self.c_bits,
            };
            let (x, y) = args_2!(inputs);
            let mask = cmp.eval(ctx, tvec!(x))?.remove(0);
            return Bin::Mul.tract().eval(ctx, tvec!(mask, y));
        }
        let c = f32::from_bits(self.c_bits);
        let shape: TVec<usize> = x.shape().into();
        let (x, y) = args_2!(inputs);
        // The result overwrites y when it has the full shape, else x.
        let y_full = *y.shape() == *shape;
        let (full, other) = if y_full { (y, x) } else { (x, y) };
        let mut out = full.into_tensor();
        {
            let bv = other.try_as_plain_ram()?;
            let bs = bv.as_slice::<f32>()?;
            let mut ov = out.try_as_plain_ram_mut()?;
            let os = ov.as_slice_mut::<f32>()?;
            let sb = other.shape();
            macro_rules! run {
                ($op:tt) => {
                    if y_full {
                        // o = y, b = x
                        broadcast_rows_in_place(os, bs, sb, &shape, |w, v| {
                            if v $op c { w } else { 0.0 * w }
                        })
                    } else {
                        // o = x, b = y
                        broadcast_rows_in_place(os, bs, sb, &shape, |v, w| {
                            if v $op c { w } else { 0.0 * w }
                        })
                    }
                };
            }
            match self.cmp {
                Cmp::Gt => run!(>),
                Cmp::Ge => run!(>=),
                Cmp::Lt => run!(<),
                Cmp::Le => run!(<=),
                Cmp::Eq => run!(==),
                Cmp::Ne => run!(!=),
            }
        }
        Ok(tvec!(out.into_tvalue()))
    }
}

impl TypedOp for MaskMul {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        Ok(tvec!(f32::fact(inputs[0].shape.clone())))
    }
    as_op!();
}

/// A product (any of tract's forms, or ours) of a [`CmpToF32`] mask with an
/// f32 tensor of the same rank that broadcasts to the mask's shape →
/// [`MaskMul`].
fn mask_mul(model: &TypedModel, node: &TypedNode) -> TractResult<Option<TypedModelPatch>> {
    let is_mul = node
        .op_as::<TypedBinOp>()
        .is_some_and(|b| b.0.is::<Mul>() && b.1.is_none())
        || node
            .op_as::<OptBinUnicast>()
            .is_some_and(|b| b.binop.is::<Mul>())
        || node
            .op_as::<OptBinByScalar>()
            .is_some_and(|b| b.binop.is::<Mul>())
        || node
            .op_as::<BroadcastBin>()
            .is_some_and(|b| b.op == Bin::Mul);
    if !is_mul || node.inputs.len() != 2 || !is_f32(model, node.id.into())? {
        return Ok(None);
    }
    let Some(out) = concrete(model, node.id.into())? else {
        return Ok(None);
    };
    for (m, other) in [(0, 1), (1, 0)] {
        let producer = model.node(node.inputs[m].node);
        let Some(cmp) = producer.op_as::<CmpToF32>() else {
            continue;
        };
        let x = producer.inputs[0];
        let y = node.inputs[other];
        let (Some(xs), Some(ys)) = (concrete(model, x)?, concrete(model, y)?) else {
            continue;
        };
        let fits =
            xs == out && ys.len() == xs.len() && xs.iter().zip(&ys).all(|(a, b)| a == b || *b == 1);
        if !fits || !is_f32(model, y)? {
            continue;
        }
        let mut patch = TypedModelPatch::default();
        let taps = patch.taps(model, &[x, y])?;
        let wire = patch.wire_node(
            &node.name,
            MaskMul {
                cmp: cmp.cmp,
                c_bits: cmp.c_bits,
            },
            &taps,
        )?;
        patch.shunt_outside(model, node.id.into(), wire[0])?;
        return Ok(Some(patch));
    }
    Ok(None)
}

// ---------------------------------------------------------------- softmax --

/// Softmax over the last axis of an f32 tensor.
#[derive(Debug, Clone, Hash, PartialEq, Eq)]
struct LastAxisSoftmax {
    tract: Softmax,
}

impl Op for LastAxisSoftmax {
    fn name(&self) -> StaticName {
        "D3ilSoftmax".into()
    }
    op_as_typed_op!();
}

impl EvalOp for LastAxisSoftmax {
    op_out_of_plan!();

    fn eval(&self, ctx: &EvalContext, inputs: TVec<TValue>) -> TractResult<TVec<TValue>> {
        let x = &inputs[0];
        let n = x.shape().last().copied().unwrap_or(0);
        if x.datum_type() != f32::datum_type() || !natural(x) || n == 0 {
            return self.tract.eval(ctx, inputs);
        }
        let mut out = args_1!(inputs).into_tensor();
        {
            let mut view = out.try_as_plain_ram_mut()?;
            let data = view.as_slice_mut::<f32>()?;
            // x − max per row, then tract's own exp kernel over the whole
            // buffer at once (the same values its per-row kernel gives: it
            // subtracts the max itself), then the sums per row.
            for row in data.chunks_exact_mut(n) {
                let max = row.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                row.iter_mut().for_each(|v| *v -= max);
            }
            Func::Softmax2
                .map_reduce_f32()?
                .run_with_params(data, 0.0)?;
            for row in data.chunks_exact_mut(n) {
                let r = row.iter().sum::<f32>().recip();
                row.iter_mut().for_each(|v| *v *= r);
            }
        }
        Ok(tvec!(out.into_tvalue()))
    }
}

impl TypedOp for LastAxisSoftmax {
    fn output_facts(&self, inputs: &[&TypedFact]) -> TractResult<TVec<TypedFact>> {
        self.tract.output_facts(inputs)
    }
    as_op!();
}

/// An f32 softmax over the last axis → [`LastAxisSoftmax`].
fn softmax(
    model: &TypedModel,
    node: &TypedNode,
    sm: &Softmax,
) -> TractResult<Option<TypedModelPatch>> {
    let Some(shape) = concrete(model, node.inputs[0])? else {
        return Ok(None);
    };
    let rank = shape.len();
    if sm.kind != SoftmaxKind::Softmax
        || sm.quant_output_dt.is_some()
        || !is_f32(model, node.inputs[0])?
        || rank == 0
        || *sm.axes != [rank - 1]
    {
        return Ok(None);
    }
    Ok(Some(TypedModelPatch::replace_single_op(
        model,
        node,
        &node.inputs,
        LastAxisSoftmax { tract: sm.clone() },
    )?))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(shape: &[usize], k: f32) -> Tensor {
        let n: usize = shape.iter().product();
        let v: Vec<f32> = (0..n)
            .map(|i| ((i as f32 + k) * 0.731).sin() * 3.0)
            .collect();
        Tensor::from_shape(shape, &v).unwrap()
    }

    fn run(model: &TypedModel, inputs: &[Tensor]) -> Vec<Tensor> {
        let plan = model.clone().into_runnable().unwrap();
        let ins: TVec<TValue> = inputs.iter().map(|t| t.clone().into_tvalue()).collect();
        plan.run(ins)
            .unwrap()
            .into_iter()
            .map(|t| t.into_tensor())
            .collect()
    }

    /// Every pattern is swapped for our kernel, and the results are tract's:
    /// bit for bit for comparisons, masks and element-wise ops (each
    /// broadcasting layout of the inner row), to rounding for the softmax.
    #[test]
    fn our_kernels_replace_tracts_and_agree_with_them() {
        let mut m = TypedModel::default();
        let a = m.add_source("a", f32::fact([2, 3, 5])).unwrap();
        let b = m.add_source("b", f32::fact([2, 1, 5])).unwrap();
        let c = m.add_source("c", f32::fact([2, 3, 1])).unwrap();
        let d = m.add_source("d", f32::fact([1, 1, 5])).unwrap();
        let bin = |m: &mut TypedModel, name: &str, op: Bin, x: OutletId, y: OutletId| {
            m.wire_node(name, op.tract(), &[x, y]).unwrap()[0]
        };
        let add = bin(&mut m, "add", Bin::Add, a, b);
        let sub = bin(&mut m, "sub", Bin::Sub, b, a);
        let mul = bin(&mut m, "mul", Bin::Mul, c, d);
        let div = bin(&mut m, "div", Bin::Div, a, c);
        let max = bin(&mut m, "max", Bin::Max, d, c);
        // The full-shape operand second: the output overwrites it.
        let mul2 = bin(&mut m, "mul2", Bin::Mul, b, a);
        let zero = m.add_const("zero", tensor3(&[[[0.5f32]]])).unwrap();
        let mut outs = vec![add, sub, mul, div, max, mul2];
        for (name, mini, left) in [
            (
                "gt",
                Box::new(CompGT) as Box<dyn tract_onnx::tract_core::ops::binary::BinMiniOp>,
                true,
            ),
            ("le", Box::new(CompLTE), false),
        ] {
            let ins = if left { [add, zero] } else { [zero, add] };
            let cmp = m.wire_node(name, TypedBinOp(mini, None), &ins).unwrap();
            let cast = m
                .wire_node(
                    format!("{name}.cast"),
                    Cast {
                        to: f32::datum_type(),
                    },
                    &cmp,
                )
                .unwrap();
            outs.push(cast[0]);
            if left {
                // The mask applied to a tensor broadcast along the middle
                // axis, and to one of its own shape.
                outs.push(bin(&mut m, "masked", Bin::Mul, b, cast[0]));
                outs.push(bin(&mut m, "masked2", Bin::Mul, cast[0], a));
            }
        }
        let sm = Softmax {
            axes: tvec![2],
            quant_output_dt: None,
            kind: SoftmaxKind::Softmax,
        };
        outs.push(m.wire_node("softmax", sm, &[add]).unwrap()[0]);
        m.select_output_outlets(&outs).unwrap();

        let inputs = [
            values(&[2, 3, 5], 0.0),
            values(&[2, 1, 5], 1.0),
            values(&[2, 3, 1], 2.0),
            values(&[1, 1, 5], 3.0),
        ];
        let want = run(&m, &inputs);
        let mut fast = m.clone();
        speed_up(&mut fast).unwrap();
        let ours: Vec<String> = fast
            .eval_order()
            .unwrap()
            .into_iter()
            .map(|n| fast.node(n).op().name().to_string())
            .filter(|n| n.starts_with("D3il"))
            .collect();
        assert_eq!(ours.len(), 11, "{ours:?}");
        let got = run(&fast, &inputs);
        for (i, (g, w)) in got.iter().zip(&want).enumerate() {
            assert_eq!(g.shape(), w.shape(), "output {i}");
            let (g, w) = (
                g.to_plain_array_view::<f32>().unwrap(),
                w.to_plain_array_view::<f32>().unwrap(),
            );
            for (x, y) in g.iter().zip(w.iter()) {
                if i < 10 {
                    assert_eq!(x.to_bits(), y.to_bits(), "output {i}: {x} vs {y}");
                } else {
                    assert!((x - y).abs() <= 1e-6, "softmax: {x} vs {y}");
                }
            }
        }
    }
}
