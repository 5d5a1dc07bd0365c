//! Element-wise `+ − × ÷ max min` of two f32 tensors broadcast along any
//! axis ([`BroadcastBin`]), and the row loops the masked product shares.

use super::*;

#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub(super) enum Bin {
    Add,
    Sub,
    Mul,
    Div,
    Max,
    Min,
}

impl Bin {
    pub(super) fn of(bin: &TypedBinOp) -> Option<Bin> {
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
    pub(super) fn tract(self) -> TypedBinOp {
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
pub(super) struct BroadcastBin {
    pub(super) op: Bin,
}

impl Op for BroadcastBin {
    fn name(&self) -> StaticName {
        format!("D3ilBroadcast{:?}", self.op).into()
    }
    op_as_typed_op!();
}

/// `out[o] = f(a[o], b[o])` over the rows of the output's last axis, each
/// input read with stride 1 or 0 (broadcast) along each axis.
pub(super) fn broadcast_rows(
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
pub(super) fn broadcast_rows_in_place(
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
pub(super) fn plain_f32(t: &Tensor) -> bool {
    t.datum_type() == f32::datum_type()
        && natural(t)
        && t.rank() > 0
        && t.shape().iter().all(|&d| d > 0)
}

/// Whether `small` broadcasts to `full` (equal rank, each axis equal or 1).
pub(super) fn broadcasts_to(small: &[usize], full: &[usize]) -> bool {
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
pub(super) fn broadcast_bin(
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
