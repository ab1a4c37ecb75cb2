//! Static checks on an untrusted ONNX policy, before tract sees it: the ops an MLP policy needs
//! and nothing that makes tensors out of a few bytes, a bounded graph, bounded constants.
//!
//! These checks are the first line; the second is the worker process the server loads and runs
//! client policies in ([`crate::SandboxedPolicy`]), with memory and time limits, since even
//! allowed ops (`Concat` of a tensor with itself, `Gather` with many indices) can fold into
//! large constants.

use tract_onnx::pb;
use tract_onnx::prelude::Framework;

use crate::error::PolicyError;

/// ONNX ops a policy may use: those the exporters write for MLPs (Gemm/MatMul layers,
/// activations, the flatten and concat of the history and the estimate, the shape arithmetic
/// around a reshape) and nothing that makes a large tensor from a small input
/// (`ConstantOfShape`, `Range`, `Expand`, `Tile`, `Pad`, `Resize`, loops, ...).
pub const ALLOWED_OPS: &[&str] = &[
    "Abs",
    "Add",
    "BatchNormalization",
    "Cast",
    "Clip",
    "Concat",
    "Constant",
    "Div",
    "Dropout",
    "Elu",
    "Exp",
    "Flatten",
    "Gather",
    "Gemm",
    "HardSigmoid",
    "HardSwish",
    "Identity",
    "LayerNormalization",
    "LeakyRelu",
    "Log",
    "MatMul",
    "Max",
    "Min",
    "Mish",
    "Mul",
    "Neg",
    "PRelu",
    "Relu",
    "Reshape",
    "Selu",
    "Shape",
    "Sigmoid",
    "Slice",
    "Softplus",
    "Softsign",
    "Split",
    "Sqrt",
    "Squeeze",
    "Sub",
    "Tanh",
    "Transpose",
    "Unsqueeze",
];

/// Bounds on an untrusted model's graph.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ModelLimits {
    /// Bytes of the serialised model. Default 16 MiB.
    pub max_bytes: usize,
    /// Nodes in the graph. Default 1024.
    pub max_nodes: usize,
    /// Elements of one initialiser or `Constant` tensor. Default 4 Mi (16 MiB of f32).
    pub max_tensor_elements: u64,
    /// Elements of all initialisers and constants together. Default 8 Mi.
    pub max_total_elements: u64,
    /// Rank of a constant tensor. Default 8.
    pub max_rank: usize,
}

impl Default for ModelLimits {
    fn default() -> Self {
        Self {
            max_bytes: 16 << 20,
            max_nodes: 1024,
            max_tensor_elements: 4 << 20,
            max_total_elements: 8 << 20,
            max_rank: 8,
        }
    }
}

fn too_large(what: String, size: u64, limit: u64) -> PolicyError {
    PolicyError::TooLarge { what, size, limit }
}

/// Elements of a constant tensor, checked against the limits.
fn tensor_elements(t: &pb::TensorProto, limits: &ModelLimits) -> Result<u64, PolicyError> {
    let name = if t.name.is_empty() {
        "a constant".to_string()
    } else {
        format!("tensor `{}`", t.name)
    };
    if t.dims.len() > limits.max_rank {
        return Err(too_large(
            format!("rank of {name}"),
            t.dims.len() as u64,
            limits.max_rank as u64,
        ));
    }
    let mut elements: u64 = 1;
    for &d in &t.dims {
        let d = u64::try_from(d).map_err(|_| PolicyError::Invalid {
            message: format!("{name} has a negative dimension {d}"),
        })?;
        elements = elements.saturating_mul(d);
    }
    if elements > limits.max_tensor_elements {
        return Err(too_large(
            format!("elements of {name}"),
            elements,
            limits.max_tensor_elements,
        ));
    }
    Ok(elements)
}

/// Check a parsed model against the op allow-list and `limits`.
pub fn check_model(proto: &pb::ModelProto, limits: &ModelLimits) -> Result<(), PolicyError> {
    let Some(graph) = proto.graph.as_ref() else {
        return Err(PolicyError::Invalid {
            message: "the model has no graph".into(),
        });
    };
    if graph.node.len() > limits.max_nodes {
        return Err(too_large(
            "nodes in the graph".into(),
            graph.node.len() as u64,
            limits.max_nodes as u64,
        ));
    }
    if !graph.sparse_initializer.is_empty() {
        return Err(PolicyError::Invalid {
            message: "sparse initialisers are not supported in a policy".into(),
        });
    }
    let mut total: u64 = 0;
    for t in &graph.initializer {
        total = total.saturating_add(tensor_elements(t, limits)?);
    }
    for node in &graph.node {
        let standard = node.domain.is_empty() || node.domain == "ai.onnx";
        if !standard || !ALLOWED_OPS.contains(&node.op_type.as_str()) {
            let op = if standard {
                node.op_type.clone()
            } else {
                format!("{}:{}", node.domain, node.op_type)
            };
            return Err(PolicyError::UnsupportedOp {
                op,
                node: node.name.clone(),
            });
        }
        for a in &node.attribute {
            if a.sparse_tensor.is_some() || !a.sparse_tensors.is_empty() {
                return Err(PolicyError::UnsupportedOp {
                    op: format!("{} with a sparse tensor", node.op_type),
                    node: node.name.clone(),
                });
            }
            if a.g.is_some() || !a.graphs.is_empty() {
                return Err(PolicyError::UnsupportedOp {
                    op: format!("{} with a subgraph", node.op_type),
                    node: node.name.clone(),
                });
            }
            if let Some(t) = &a.t {
                total = total.saturating_add(tensor_elements(t, limits)?);
            }
            for t in &a.tensors {
                total = total.saturating_add(tensor_elements(t, limits)?);
            }
            // Plain number lists (a Reshape's or Slice's) are bounded by the model size.
        }
    }
    if total > limits.max_total_elements {
        return Err(too_large(
            "elements of all constants".into(),
            total,
            limits.max_total_elements,
        ));
    }
    Ok(())
}

/// Parse `bytes` as an ONNX model and check it (size, ops, constants).
pub fn parse_checked(bytes: &[u8], limits: &ModelLimits) -> Result<pb::ModelProto, PolicyError> {
    if bytes.len() > limits.max_bytes {
        return Err(too_large(
            "bytes of the model".into(),
            bytes.len() as u64,
            limits.max_bytes as u64,
        ));
    }
    let proto = tract_onnx::onnx()
        .proto_model_for_read(&mut &bytes[..])
        .map_err(|e| PolicyError::Parse {
            len: bytes.len(),
            message: format!("{e:#}"),
        })?;
    check_model(&proto, limits)?;
    Ok(proto)
}
