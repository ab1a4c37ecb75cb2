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
    /// Bytes the decoded model may take in memory, as [`scan_wire`] bounds it from the wire
    /// format before anything is decoded. Default 128 MiB (the paper's network: under 2 MiB).
    pub max_decoded_bytes: u64,
}

impl Default for ModelLimits {
    fn default() -> Self {
        Self {
            max_bytes: 16 << 20,
            max_nodes: 1024,
            max_tensor_elements: 4 << 20,
            max_total_elements: 8 << 20,
            max_rank: 8,
            max_decoded_bytes: 128 << 20,
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

/// Parse `bytes` as an ONNX model and check it (size, wire format, ops, constants).
pub fn parse_checked(bytes: &[u8], limits: &ModelLimits) -> Result<pb::ModelProto, PolicyError> {
    scan_wire(bytes, limits)?;
    let proto = tract_onnx::onnx()
        .proto_model_for_read(&mut &bytes[..])
        .map_err(|e| PolicyError::Parse {
            len: bytes.len(),
            message: format!("{e:#}"),
        })?;
    check_model(&proto, limits)?;
    Ok(proto)
}

// ---- Wire-format scan ---------------------------------------------------------------------

/// The ONNX messages tract's decoder builds (tract-onnx's `onnx.proto`, as prost generates it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Msg {
    Model,
    Graph,
    Node,
    Attribute,
    Tensor,
    Segment,
    SparseTensor,
    ValueInfo,
    Type,
    TypeTensor,
    Shape,
    Dimension,
    OpsetId,
    StringEntry,
    TensorAnnotation,
    TrainingInfo,
    Function,
}

impl Msg {
    /// Bytes one decoded value of this message takes inline (in its parent or a `Vec`).
    fn size(self) -> u64 {
        use std::mem::size_of;
        (match self {
            Msg::Model => size_of::<pb::ModelProto>(),
            Msg::Graph => size_of::<pb::GraphProto>(),
            Msg::Node => size_of::<pb::NodeProto>(),
            Msg::Attribute => size_of::<pb::AttributeProto>(),
            Msg::Tensor => size_of::<pb::TensorProto>(),
            Msg::Segment => size_of::<pb::tensor_proto::Segment>(),
            Msg::SparseTensor => size_of::<pb::SparseTensorProto>(),
            Msg::ValueInfo => size_of::<pb::ValueInfoProto>(),
            Msg::Type => size_of::<pb::TypeProto>(),
            Msg::TypeTensor => size_of::<pb::type_proto::Tensor>(),
            Msg::Shape => size_of::<pb::TensorShapeProto>(),
            Msg::Dimension => size_of::<pb::tensor_shape_proto::Dimension>(),
            Msg::OpsetId => size_of::<pb::OperatorSetIdProto>(),
            Msg::StringEntry => size_of::<pb::StringStringEntryProto>(),
            Msg::TensorAnnotation => size_of::<pb::TensorAnnotation>(),
            Msg::TrainingInfo => size_of::<pb::TrainingInfoProto>(),
            Msg::Function => size_of::<pb::FunctionProto>(),
        }) as u64
    }

    /// How field `tag` of this message decodes.
    fn field(self, tag: u64) -> Field {
        use Field::*;
        const STRING: Field = Bytes { repeated: false };
        const STRINGS: Field = Bytes { repeated: true };
        let message = |m: Msg| Message {
            msg: m,
            repeated: false,
        };
        let messages = |m: Msg| Message {
            msg: m,
            repeated: true,
        };
        match (self, tag) {
            (Msg::Model, 7) => message(Msg::Graph),
            (Msg::Model, 8) => messages(Msg::OpsetId),
            (Msg::Model, 14) => messages(Msg::StringEntry),
            (Msg::Model, 20) => messages(Msg::TrainingInfo),
            (Msg::Model, 25) => messages(Msg::Function),
            (Msg::Model, 2 | 3 | 4 | 6) => STRING,
            (Msg::Graph, 1) => messages(Msg::Node),
            (Msg::Graph, 5) => messages(Msg::Tensor),
            (Msg::Graph, 15) => messages(Msg::SparseTensor),
            (Msg::Graph, 11..=13) => messages(Msg::ValueInfo),
            (Msg::Graph, 14) => messages(Msg::TensorAnnotation),
            (Msg::Graph, 2 | 10) => STRING,
            (Msg::Node, 1 | 2) => STRINGS,
            (Msg::Node, 3 | 4 | 6 | 7) => STRING,
            (Msg::Node, 5) => messages(Msg::Attribute),
            (Msg::Attribute, 5) => message(Msg::Tensor),
            (Msg::Attribute, 6) => message(Msg::Graph),
            (Msg::Attribute, 22) => message(Msg::SparseTensor),
            (Msg::Attribute, 7) => Numbers { width: 4 },
            (Msg::Attribute, 8) => Numbers { width: 8 },
            (Msg::Attribute, 9) => STRINGS,
            (Msg::Attribute, 10) => messages(Msg::Tensor),
            (Msg::Attribute, 11) => messages(Msg::Graph),
            (Msg::Attribute, 23) => messages(Msg::SparseTensor),
            (Msg::Attribute, 15) => messages(Msg::Type),
            (Msg::Attribute, 1 | 4 | 13 | 21) => STRING,
            (Msg::Tensor, 1 | 7 | 10 | 11) => Numbers { width: 8 },
            (Msg::Tensor, 4 | 5) => Numbers { width: 4 },
            (Msg::Tensor, 3) => message(Msg::Segment),
            (Msg::Tensor, 6) => STRINGS,
            (Msg::Tensor, 8 | 9 | 12) => STRING,
            (Msg::Tensor, 13) => messages(Msg::StringEntry),
            (Msg::SparseTensor, 1 | 2) => message(Msg::Tensor),
            (Msg::SparseTensor, 3) => Numbers { width: 8 },
            (Msg::ValueInfo, 2) => message(Msg::Type),
            (Msg::ValueInfo, 1 | 3) => STRING,
            (Msg::Type, 1) => message(Msg::TypeTensor),
            (Msg::Type, 6) => STRING,
            (Msg::TypeTensor, 2) => message(Msg::Shape),
            (Msg::Shape, 1) => messages(Msg::Dimension),
            (Msg::Dimension, 2 | 3) => STRING,
            (Msg::OpsetId, 1) => STRING,
            (Msg::StringEntry, 1 | 2) => STRING,
            (Msg::TensorAnnotation, 1) => STRING,
            (Msg::TensorAnnotation, 2) => messages(Msg::StringEntry),
            (Msg::TrainingInfo, 1 | 2) => message(Msg::Graph),
            (Msg::TrainingInfo, 3 | 4) => messages(Msg::StringEntry),
            (Msg::Function, 1 | 8 | 10) => STRING,
            (Msg::Function, 4..=6) => STRINGS,
            (Msg::Function, 7) => messages(Msg::Node),
            (Msg::Function, 9) => messages(Msg::OpsetId),
            // Single numbers (decoded inline) and fields the decoder skips.
            _ => Other,
        }
    }
}

/// How one field decodes.
#[derive(Clone, Copy, Debug)]
enum Field {
    /// A message: inline when single, one `Vec` element per entry when repeated.
    Message { msg: Msg, repeated: bool },
    /// A string or bytes; repeated: one `Vec` element (a `Vec<u8>`/`String`) per entry.
    Bytes { repeated: bool },
    /// Repeated numbers of `width` bytes in memory, packed or one per entry.
    Numbers { width: u64 },
    /// A single number, or a field the decoder does not keep.
    Other,
}

/// Deepest nesting of messages the scan follows (a policy needs 7: model, graph, value info,
/// type, tensor type, shape, dimension; prost itself stops at 100).
const MAX_WIRE_DEPTH: usize = 32;
/// Bytes of a `Vec`, `String` or `Vec<u8>` header.
const VEC_HEADER: u64 = 24;

/// What the scan found so far.
#[derive(Default)]
struct Scan {
    /// Upper bound on the bytes the decoded model takes.
    decoded: u64,
    /// Nodes of the main graph.
    nodes: u64,
}

fn wire_error(len: usize, message: impl Into<String>) -> PolicyError {
    PolicyError::Parse {
        len,
        message: message.into(),
    }
}

fn read_varint(bytes: &[u8], at: &mut usize) -> Option<u64> {
    let mut value = 0u64;
    for shift in (0..70).step_by(7) {
        let b = *bytes.get(*at)?;
        *at += 1;
        value |= u64::from(b & 0x7f).checked_shl(shift).unwrap_or(0);
        if b & 0x80 == 0 {
            return Some(value);
        }
    }
    None
}

/// Walk one message's fields, adding to `scan` what decoding them allocates.
fn scan_message(
    bytes: &[u8],
    msg: Msg,
    depth: usize,
    main_graph: bool,
    total: usize,
    scan: &mut Scan,
) -> Result<(), PolicyError> {
    if depth > MAX_WIRE_DEPTH {
        return Err(wire_error(
            total,
            format!("messages nest deeper than {MAX_WIRE_DEPTH} levels"),
        ));
    }
    let truncated = || wire_error(total, "truncated or malformed protobuf");
    let mut at = 0;
    while at < bytes.len() {
        let key = read_varint(bytes, &mut at).ok_or_else(truncated)?;
        let (tag, wire) = (key >> 3, key & 7);
        if tag == 0 {
            return Err(wire_error(total, "a protobuf field numbered 0"));
        }
        let field = msg.field(tag);
        // A `Vec` that grows by doubling holds up to twice its elements, and while it moves to
        // a larger block both blocks are live: three times its elements at the peak.
        let per_entry = |inline: u64| 3 * inline;
        match wire {
            0 => {
                read_varint(bytes, &mut at).ok_or_else(truncated)?;
                if let Field::Numbers { width } = field {
                    scan.decoded = scan.decoded.saturating_add(per_entry(width));
                }
            }
            1 | 5 => {
                let width = if wire == 1 { 8 } else { 4 };
                at = at
                    .checked_add(width)
                    .filter(|&end| end <= bytes.len())
                    .ok_or_else(truncated)?;
                if let Field::Numbers { width } = field {
                    scan.decoded = scan.decoded.saturating_add(per_entry(width));
                }
            }
            2 => {
                let len = read_varint(bytes, &mut at).ok_or_else(truncated)?;
                let end = usize::try_from(len)
                    .ok()
                    .and_then(|len| at.checked_add(len))
                    .filter(|&end| end <= bytes.len())
                    .ok_or_else(truncated)?;
                let body = &bytes[at..end];
                at = end;
                let added = match field {
                    Field::Message { msg: sub, repeated } => {
                        if main_graph && msg == Msg::Graph && tag == 1 {
                            scan.nodes += 1;
                        }
                        scan_message(
                            body,
                            sub,
                            depth + 1,
                            main_graph && msg == Msg::Model,
                            total,
                            scan,
                        )?;
                        if repeated { per_entry(sub.size()) } else { 0 }
                    }
                    Field::Bytes { repeated } => {
                        body.len() as u64 + if repeated { per_entry(VEC_HEADER) } else { 0 }
                    }
                    // Packed: at most one number per byte (varints), fewer for fixed widths.
                    Field::Numbers { width } => per_entry(width).saturating_mul(body.len() as u64),
                    Field::Other => 0,
                };
                scan.decoded = scan.decoded.saturating_add(added);
            }
            _ => {
                return Err(wire_error(
                    total,
                    format!("protobuf wire type {wire} (groups) is not used by ONNX"),
                ));
            }
        }
    }
    Ok(())
}

/// Bound what decoding `bytes` as an ONNX model would allocate, from the wire format alone
/// (nothing is decoded): refuse a model over `limits.max_bytes`, with more nodes in its graph
/// than `limits.max_nodes`, or whose decoded form would take more than
/// `limits.max_decoded_bytes`. Protobuf amplifies: an empty repeated message is two bytes on
/// the wire and a whole default struct (hundreds of bytes) in memory, so a 15 MiB model of empty
/// entries decodes to gigabytes. Returns the bound.
pub fn scan_wire(bytes: &[u8], limits: &ModelLimits) -> Result<u64, PolicyError> {
    if bytes.len() > limits.max_bytes {
        return Err(too_large(
            "bytes of the model".into(),
            bytes.len() as u64,
            limits.max_bytes as u64,
        ));
    }
    let mut scan = Scan {
        decoded: Msg::Model.size(),
        nodes: 0,
    };
    scan_message(bytes, Msg::Model, 0, true, bytes.len(), &mut scan)?;
    if scan.nodes > limits.max_nodes as u64 {
        return Err(too_large(
            "nodes in the graph".into(),
            scan.nodes,
            limits.max_nodes as u64,
        ));
    }
    if scan.decoded > limits.max_decoded_bytes {
        return Err(too_large(
            "decoded size in bytes (bounded from its protobuf encoding)".into(),
            scan.decoded,
            limits.max_decoded_bytes,
        ));
    }
    Ok(scan.decoded)
}
