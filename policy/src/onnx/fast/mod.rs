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

mod broadcast;
mod mask;
mod softmax;

use broadcast::*;
use mask::*;
use softmax::*;

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
