//! Comparisons of an f32 tensor with a scalar turned into 0/1
//! ([`CmpToF32`]), and such a mask multiplied with a tensor ([`MaskMul`]).

use super::*;

#[derive(Debug, Clone, Copy, Hash, PartialEq, Eq)]
pub(super) enum Cmp {
    Gt,
    Ge,
    Lt,
    Le,
    Eq,
    Ne,
}

impl Cmp {
    /// The comparison with its operands swapped (`c < x` is `x > c`).
    pub(super) fn flip(self) -> Cmp {
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
pub(super) struct CmpToF32 {
    pub(super) cmp: Cmp,
    pub(super) c_bits: u32,
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

pub(super) fn cmp_of(bin: &TypedBinOp) -> Option<Cmp> {
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
pub(super) fn cmp_cast(
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

/// `(x cmp c) as f32 × y`, i.e. `y` where the comparison holds and `0 × y`
/// elsewhere (the same bits as the product with 1.0 or 0.0), with `y`
/// broadcast to `x`'s shape: a relu's derivative applied to a gradient.
#[derive(Debug, Clone, Hash, PartialEq, Eq)]
pub(super) struct MaskMul {
    pub(super) cmp: Cmp,
    pub(super) c_bits: u32,
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
pub(super) fn mask_mul(
    model: &TypedModel,
    node: &TypedNode,
) -> TractResult<Option<TypedModelPatch>> {
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
