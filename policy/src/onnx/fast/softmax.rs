//! Softmax over the last axis of short f32 rows ([`LastAxisSoftmax`]).

use super::*;

/// Softmax over the last axis of an f32 tensor.
#[derive(Debug, Clone, Hash, PartialEq, Eq)]
pub(super) struct LastAxisSoftmax {
    pub(super) tract: Softmax,
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
pub(super) fn softmax(
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
