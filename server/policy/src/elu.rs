//! A fused ELU for tract.
//!
//! tract-onnx expands an ONNX `Elu` into four element-wise nodes, `0 < x`, `exp(x)`,
//! `exp - 1` (times alpha unless it is 1) and `iff`, each a full pass over the layer's
//! activations with a tensor of its own. [`fuse_elu`] puts one in-place node in their place
//! (on the paper network at batch 4096, one thread: ~45 -> ~40 ms CPU per call) that computes
//! `x > 0 ? x : alpha * (exp(x) - 1)` in a single pass, with tract's own vectorised `exp`
//! kernel, so the results are those of the expansion.

use tract_onnx::prelude::*;
use tract_onnx::tract_core::internal::{Op, TypedModelPatch, Validation};
use tract_onnx::tract_core::ops::binary::TypedBinOp;
use tract_onnx::tract_core::ops::element_wise::{ElementWiseMiniOp, ElementWiseOp};
use tract_onnx::tract_core::ops::logic::{CompLT, Iff};
use tract_onnx::tract_core::ops::math::{Exp, Mul, Sub};
use tract_onnx::tract_core::tract_linalg::Func;

/// Values per block: the block and its `exp` fit in L1, so the layer is read and written once.
/// A multiple of the exp kernels' width (16 to 64 values).
const BLOCK: usize = 256;

/// The `exp` buffer, aligned as tract's kernels want it (64 bytes for AVX-512): a misaligned
/// slice has its head and tail done through a scratch copy, a full kernel step each.
#[repr(C, align(64))]
struct Aligned([f32; BLOCK]);

/// `x > 0 ? x : alpha * (exp(x) - 1)`, in place.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) struct FusedElu {
    /// `alpha` as bits: tract compares ops for equality (`Eq`), which f32 does not have.
    alpha_bits: u32,
}

impl FusedElu {
    fn alpha(&self) -> f32 {
        f32::from_bits(self.alpha_bits)
    }
}

impl ElementWiseMiniOp for FusedElu {
    fn name(&self) -> String {
        "UnigaitFusedElu".into()
    }

    fn validation(&self) -> Validation {
        // As the `exp` it replaces: a kernel approximation, not bit-exact with libm.
        Validation::Rounding
    }

    fn info(&self) -> TractResult<Vec<String>> {
        Ok(vec![format!("alpha: {}", self.alpha())])
    }

    fn eval_in_place(&self, t: &mut Tensor, _out_dt: Option<DatumType>) -> TractResult<()> {
        let exp = Func::Exp.ew_f32()?;
        let alpha = self.alpha();
        let mut plain = t.try_as_plain_ram_mut()?;
        let xs = plain.as_slice_mut::<f32>()?;
        let mut buffer = Aligned([0.0; BLOCK]);
        for block in xs.chunks_mut(BLOCK) {
            let e = &mut buffer.0[..block.len()];
            // Only the non-positive side's exp is used; the rest is 0 so the kernel never
            // overflows. NaN is not `> 0`: it goes through exp and comes out NaN, as it did
            // from the expansion.
            for (e, x) in e.iter_mut().zip(block.iter()) {
                *e = if *x > 0.0 { 0.0 } else { *x };
            }
            exp.run(e)?;
            // A select, not a conditional store, so the loop vectorises.
            for (x, e) in block.iter_mut().zip(e.iter()) {
                *x = if *x > 0.0 { *x } else { alpha * (*e - 1.0) };
            }
        }
        Ok(())
    }
}

/// The single value of a constant outlet whose elements are all equal, as f32.
fn uniform_f32(model: &TypedModel, outlet: OutletId) -> Option<f32> {
    let fact = model.outlet_fact(outlet).ok()?;
    let tensor = fact.uniform.as_ref().or(fact.konst.as_ref())?;
    if tensor.datum_type() != f32::datum_type() {
        return None;
    }
    let plain = tensor.try_as_plain_ram().ok()?;
    let values = plain.as_slice::<f32>().ok()?;
    let first = *values.first()?;
    values.iter().all(|v| *v == first).then_some(first)
}

/// The node feeding `outlet`, if its op is a `T`.
fn producer<T: Op>(model: &TypedModel, outlet: OutletId) -> Option<(&TypedNode, &T)> {
    let node = model.node(outlet.node);
    let op = node.op_as::<T>()?;
    Some((node, op))
}

/// If `node` is the `iff` of tract's ELU expansion of `x`, its input `x` and alpha.
fn match_elu(model: &TypedModel, node: &TypedNode) -> Option<(OutletId, f32)> {
    node.op_as::<Iff>()?;
    let [test, x, negative] = node.inputs[..] else {
        return None;
    };
    if model.outlet_fact(x).ok()?.datum_type != f32::datum_type() {
        return None;
    }
    // test = 0 < x
    let (test_node, lt) = producer::<TypedBinOp>(model, test)?;
    lt.0.downcast_ref::<CompLT>()?;
    if test_node.inputs[1] != x || uniform_f32(model, test_node.inputs[0]) != Some(0.0) {
        return None;
    }
    // negative = alpha * (exp(x) - 1), the product dropped when alpha is 1
    let (mut minus_one, mut alpha) = (negative, 1.0);
    if let Some((mul_node, mul)) = producer::<TypedBinOp>(model, negative)
        && mul.0.is::<Mul>()
    {
        let [a, b] = mul_node.inputs[..] else {
            return None;
        };
        (minus_one, alpha) = match (uniform_f32(model, a), uniform_f32(model, b)) {
            (Some(v), _) => (b, v),
            (_, Some(v)) => (a, v),
            _ => return None,
        };
    }
    let (sub_node, sub) = producer::<TypedBinOp>(model, minus_one)?;
    if !sub.0.is::<Sub>() || uniform_f32(model, sub_node.inputs[1]) != Some(1.0) {
        return None;
    }
    let (exp_node, exp) = producer::<ElementWiseOp>(model, sub_node.inputs[0])?;
    if !exp.0.is::<Exp>() || exp_node.inputs[..] != [x] {
        return None;
    }
    // The shapes must agree or the fused op (shaped as x) would change the output shape.
    let out = model.outlet_fact(node.id.into()).ok()?;
    let input = model.outlet_fact(x).ok()?;
    (out.shape == input.shape).then_some((x, alpha))
}

/// Replace every ELU expansion in `model` by one [`FusedElu`] node. The expansion's other
/// nodes become unused and go at the next declutter (`into_optimized` starts with one).
/// Returns how many were fused.
pub(crate) fn fuse_elu(model: &mut TypedModel) -> TractResult<usize> {
    let found: Vec<(usize, OutletId, f32)> = model
        .nodes()
        .iter()
        .filter_map(|n| match_elu(model, n).map(|(x, alpha)| (n.id, x, alpha)))
        .collect();
    for &(id, x, alpha) in &found {
        let op = ElementWiseOp(
            Box::new(FusedElu {
                alpha_bits: alpha.to_bits(),
            }),
            None,
        );
        TypedModelPatch::replace_single_op(model, model.node(id), &[x], op)?.apply(model)?;
    }
    Ok(found.len())
}

#[cfg(test)]
mod tests {
    use tract_onnx::tract_hir::ops::activations::Elu;
    use tract_onnx::tract_hir::ops::expandable::expand;

    use super::*;

    /// tract's own expansion of ONNX `Elu(alpha)` over a `[n]` input, decluttered.
    fn expanded(alpha: f32, n: usize) -> TypedModel {
        let mut model = InferenceModel::default();
        let x = model.add_source("x", f32::fact([n]).into()).unwrap();
        let y = model.wire_node("elu", expand(Elu(alpha)), &[x]).unwrap();
        model.select_output_outlets(&y).unwrap();
        model.into_typed().unwrap().into_decluttered().unwrap()
    }

    fn run(model: TypedModel, input: &[f32]) -> Vec<f32> {
        let plan = model.into_optimized().unwrap().into_runnable().unwrap();
        let x = Tensor::from_shape(&[input.len()], input).unwrap();
        let out = plan.run(tvec!(x.into())).unwrap();
        let plain = out[0].try_as_plain_ram().unwrap();
        plain.as_slice::<f32>().unwrap().to_vec()
    }

    #[test]
    fn fused_elu_gives_the_expansion_results() {
        // Several blocks and a ragged tail; both signs, zero, huge, infinite and NaN values.
        let mut input: Vec<f32> = (0..1000).map(|i| (i as f32 - 500.0) / 37.0).collect();
        input.extend([0.0, -0.0, 1e-7, -1e-7, 100.0, -100.0, 1e30, -1e30]);
        input.extend([
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::NAN,
            f32::MIN_POSITIVE,
        ]);
        for alpha in [1.0, 0.5, 2.0] {
            let mut fused = expanded(alpha, input.len());
            assert_eq!(fuse_elu(&mut fused).unwrap(), 1, "alpha {alpha}");
            let want = run(expanded(alpha, input.len()), &input);
            let got = run(fused, &input);
            for ((x, w), g) in input.iter().zip(&want).zip(&got) {
                // The same exp kernel on the same values: equal, not just close.
                assert!(
                    w == g || (w.is_nan() && g.is_nan()),
                    "alpha {alpha}, x {x}: expansion {w}, fused {g}"
                );
            }
        }
    }

    #[test]
    fn fused_elu_replaces_the_expansion_nodes() {
        let mut model = expanded(0.5, 64);
        fuse_elu(&mut model).unwrap();
        let model = model.into_optimized().unwrap();
        let ops: Vec<String> = model
            .nodes()
            .iter()
            .map(|n| n.op.name().into_owned())
            .collect();
        assert!(ops.iter().any(|o| o == "UnigaitFusedElu"), "{ops:?}");
        assert!(!ops.iter().any(|o| o == "Iff" || o == "Exp"), "{ops:?}");
    }
}
