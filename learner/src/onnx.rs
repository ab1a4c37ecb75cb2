//! The fused policy as ONNX: the layout the Python learner exports and the server serves.
//!
//! Input `obs_history` f32 [batch, H, obs] (o_t, o_{t-1}, ...), output `actions` f32
//! [batch, A] (the actor's mean), opset 17: `Flatten`, the estimator's `Gemm`/`Elu` layers,
//! `Concat` of the flat history and the estimate, the actor's layers. No normalisation (the
//! Python learner has none).
//!
//! The ModelProto is written with the subset of onnx.proto those nodes need, as prost messages
//! declared here (field numbers from onnx.proto3): the learner then depends on prost alone,
//! which the client already brings, rather than on tract-onnx (tract-core, tract-linalg, ...),
//! which only the server needs.

use prost::Message;

use crate::Result;
use crate::nets::{self, Mlp};

/// ONNX opset of the export (as the Python learner's).
pub const OPSET: i64 = 17;
/// IR version of opset 17.
const IR_VERSION: i64 = 8;
/// `TensorProto.DataType` FLOAT.
const FLOAT: i32 = 1;
/// `AttributeProto.AttributeType` FLOAT and INT.
const ATTR_FLOAT: i32 = 1;
const ATTR_INT: i32 = 2;

/// onnx.proto `ModelProto` (the fields written).
#[derive(Clone, PartialEq, Message)]
pub struct ModelProto {
    /// IR version.
    #[prost(int64, tag = "1")]
    pub ir_version: i64,
    /// Producer.
    #[prost(string, tag = "2")]
    pub producer_name: String,
    /// The graph.
    #[prost(message, optional, tag = "7")]
    pub graph: Option<GraphProto>,
    /// Opsets.
    #[prost(message, repeated, tag = "8")]
    pub opset_import: Vec<OperatorSetIdProto>,
    /// Named strings: the physics engine the policy trained on.
    #[prost(message, repeated, tag = "14")]
    pub metadata_props: Vec<StringStringEntryProto>,
}

/// onnx.proto `StringStringEntryProto`.
#[derive(Clone, PartialEq, Message)]
pub struct StringStringEntryProto {
    /// Key.
    #[prost(string, tag = "1")]
    pub key: String,
    /// Value.
    #[prost(string, tag = "2")]
    pub value: String,
}

/// The metadata key of the physics engine a policy trained on, which the server evaluates it
/// on unless told otherwise (decision record 0026; the server's `PHYSICS_ENGINE_KEY`).
pub const PHYSICS_ENGINE_KEY: &str = "unigait.physics_engine";

/// onnx.proto `OperatorSetIdProto`.
#[derive(Clone, PartialEq, Message)]
pub struct OperatorSetIdProto {
    /// Domain ("" = the default).
    #[prost(string, tag = "1")]
    pub domain: String,
    /// Version.
    #[prost(int64, tag = "2")]
    pub version: i64,
}

/// onnx.proto `GraphProto`.
#[derive(Clone, PartialEq, Message)]
pub struct GraphProto {
    /// Nodes in order.
    #[prost(message, repeated, tag = "1")]
    pub node: Vec<NodeProto>,
    /// Name.
    #[prost(string, tag = "2")]
    pub name: String,
    /// Weights.
    #[prost(message, repeated, tag = "5")]
    pub initializer: Vec<TensorProto>,
    /// Inputs.
    #[prost(message, repeated, tag = "11")]
    pub input: Vec<ValueInfoProto>,
    /// Outputs.
    #[prost(message, repeated, tag = "12")]
    pub output: Vec<ValueInfoProto>,
}

/// onnx.proto `NodeProto`.
#[derive(Clone, PartialEq, Message)]
pub struct NodeProto {
    /// Inputs.
    #[prost(string, repeated, tag = "1")]
    pub input: Vec<String>,
    /// Outputs.
    #[prost(string, repeated, tag = "2")]
    pub output: Vec<String>,
    /// Name.
    #[prost(string, tag = "3")]
    pub name: String,
    /// Operator.
    #[prost(string, tag = "4")]
    pub op_type: String,
    /// Attributes.
    #[prost(message, repeated, tag = "5")]
    pub attribute: Vec<AttributeProto>,
}

/// onnx.proto `AttributeProto` (float and int attributes).
#[derive(Clone, PartialEq, Message)]
pub struct AttributeProto {
    /// Name.
    #[prost(string, tag = "1")]
    pub name: String,
    /// A float value.
    #[prost(float, tag = "2")]
    pub f: f32,
    /// An int value.
    #[prost(int64, tag = "3")]
    pub i: i64,
    /// Which value.
    #[prost(int32, tag = "20")]
    pub r#type: i32,
}

/// onnx.proto `TensorProto` (f32 in `raw_data`).
#[derive(Clone, PartialEq, Message)]
pub struct TensorProto {
    /// Shape.
    #[prost(int64, repeated, tag = "1")]
    pub dims: Vec<i64>,
    /// Element type.
    #[prost(int32, tag = "2")]
    pub data_type: i32,
    /// Name.
    #[prost(string, tag = "8")]
    pub name: String,
    /// Little-endian values.
    #[prost(bytes = "vec", tag = "9")]
    pub raw_data: Vec<u8>,
}

/// onnx.proto `ValueInfoProto`.
#[derive(Clone, PartialEq, Message)]
pub struct ValueInfoProto {
    /// Name.
    #[prost(string, tag = "1")]
    pub name: String,
    /// Type.
    #[prost(message, optional, tag = "2")]
    pub r#type: Option<TypeProto>,
}

/// onnx.proto `TypeProto` (tensors only).
#[derive(Clone, PartialEq, Message)]
pub struct TypeProto {
    /// The tensor type.
    #[prost(message, optional, tag = "1")]
    pub tensor_type: Option<TensorTypeProto>,
}

/// onnx.proto `TypeProto.Tensor`.
#[derive(Clone, PartialEq, Message)]
pub struct TensorTypeProto {
    /// Element type.
    #[prost(int32, tag = "1")]
    pub elem_type: i32,
    /// Shape.
    #[prost(message, optional, tag = "2")]
    pub shape: Option<TensorShapeProto>,
}

/// onnx.proto `TensorShapeProto`.
#[derive(Clone, PartialEq, Message)]
pub struct TensorShapeProto {
    /// Dimensions.
    #[prost(message, repeated, tag = "1")]
    pub dim: Vec<Dimension>,
}

/// onnx.proto `TensorShapeProto.Dimension`.
#[derive(Clone, PartialEq, Message)]
pub struct Dimension {
    /// A fixed size or a named one.
    #[prost(oneof = "DimValue", tags = "1, 2")]
    pub value: Option<DimValue>,
}

/// The value of a [`Dimension`].
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum DimValue {
    /// Fixed.
    #[prost(int64, tag = "1")]
    DimValue(i64),
    /// Symbolic.
    #[prost(string, tag = "2")]
    DimParam(String),
}

fn value_info(name: &str, dims: &[DimValue]) -> ValueInfoProto {
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            tensor_type: Some(TensorTypeProto {
                elem_type: FLOAT,
                shape: Some(TensorShapeProto {
                    dim: dims
                        .iter()
                        .map(|d| Dimension {
                            value: Some(d.clone()),
                        })
                        .collect(),
                }),
            }),
        }),
    }
}

fn node(
    op: &str,
    name: &str,
    input: &[&str],
    output: &str,
    attribute: Vec<AttributeProto>,
) -> NodeProto {
    NodeProto {
        input: input.iter().map(|s| s.to_string()).collect(),
        output: vec![output.into()],
        name: name.into(),
        op_type: op.into(),
        attribute,
    }
}

fn int_attr(name: &str, i: i64) -> AttributeProto {
    AttributeProto {
        name: name.into(),
        i,
        r#type: ATTR_INT,
        ..Default::default()
    }
}

fn tensor(name: &str, dims: &[usize], values: &[f32]) -> TensorProto {
    TensorProto {
        dims: dims.iter().map(|&d| d as i64).collect(),
        data_type: FLOAT,
        name: name.into(),
        raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
    }
}

/// Append `mlp`'s layers reading `input`, named `prefix.*`, its output named `output`.
fn add_mlp(g: &mut GraphProto, mlp: &Mlp, prefix: &str, input: &str, output: &str) -> Result<()> {
    let last = mlp.layers.len().saturating_sub(1);
    let mut x = input.to_string();
    for (i, layer) in mlp.layers.iter().enumerate() {
        let w = layer.weight.val();
        let [inp, out] = w.dims();
        let (wn, bn) = (format!("{prefix}.{i}.weight"), format!("{prefix}.{i}.bias"));
        g.initializer
            .push(tensor(&wn, &[inp, out], &nets::values(w)?));
        let bias = match &layer.bias {
            Some(b) => nets::values(b.val())?,
            None => vec![0.0; out],
        };
        g.initializer.push(tensor(&bn, &[out], &bias));
        let y = if i == last {
            output.to_string()
        } else {
            format!("{prefix}.{i}.linear")
        };
        // burn's weight is [in, out]: Gemm's B as it is (transB 0).
        g.node.push(node(
            "Gemm",
            &format!("{prefix}.{i}.gemm"),
            &[&x, &wn, &bn],
            &y,
            vec![],
        ));
        x = y;
        if i < last {
            let a = format!("{prefix}.{i}.elu");
            let alpha = AttributeProto {
                name: "alpha".into(),
                f: 1.0,
                r#type: ATTR_FLOAT,
                ..Default::default()
            };
            g.node.push(node("Elu", &a, &[&x], &a, vec![alpha]));
            x = a;
        }
    }
    Ok(())
}

/// The fused estimator + actor as ONNX bytes: `obs_history` [batch, `history`, `obs_dim`] ->
/// `actions` [batch, `num_actions`], stamped with the `physics_engine` it trained on.
pub fn export_policy(
    estimator: &Mlp,
    actor: &Mlp,
    history: usize,
    obs_dim: usize,
    num_actions: usize,
    physics_engine: &str,
) -> Result<Vec<u8>> {
    let mut g = GraphProto {
        name: "unigait_policy".into(),
        input: vec![value_info(
            "obs_history",
            &[
                DimValue::DimParam("batch".into()),
                DimValue::DimValue(history as i64),
                DimValue::DimValue(obs_dim as i64),
            ],
        )],
        output: vec![value_info(
            "actions",
            &[
                DimValue::DimParam("batch".into()),
                DimValue::DimValue(num_actions as i64),
            ],
        )],
        ..Default::default()
    };
    g.node.push(node(
        "Flatten",
        "flatten",
        &["obs_history"],
        "flat",
        vec![int_attr("axis", 1)],
    ));
    add_mlp(&mut g, estimator, "estimator", "flat", "estimate")?;
    g.node.push(node(
        "Concat",
        "concat",
        &["flat", "estimate"],
        "actor_in",
        vec![int_attr("axis", 1)],
    ));
    add_mlp(&mut g, actor, "actor", "actor_in", "actions")?;
    let model = ModelProto {
        ir_version: IR_VERSION,
        producer_name: "unigait-learner".into(),
        graph: Some(g),
        opset_import: vec![OperatorSetIdProto {
            domain: String::new(),
            version: OPSET,
        }],
        metadata_props: vec![StringStringEntryProto {
            key: PHYSICS_ENGINE_KEY.into(),
            value: physics_engine.into(),
        }],
    };
    Ok(model.encode_to_vec())
}
