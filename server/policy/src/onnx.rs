//! ONNX policies run with tract: load, check the shapes, make the batch symbolic, run batched.

use std::collections::HashSet;
use std::path::Path;
use std::sync::Arc;

use tract_onnx::pb;
use tract_onnx::pb::tensor_shape_proto::dimension::Value as DimValue;
use tract_onnx::prelude::*;

use crate::error::PolicyError;
use crate::policy::{Policy, PolicySpec};

/// ONNX `TensorProto.DataType` code of f32.
const ONNX_FLOAT: i32 = 1;

/// Symbol used for the batch when the graph's input names none.
const DEFAULT_BATCH_SYMBOL: &str = "batch";

/// How the graph takes the history.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputLayout {
    /// `[batch, history, obs_dim]` (the spec's layout).
    Stacked,
    /// `[batch, history * obs_dim]`: the same memory, flattened (o_t first).
    Flat,
}

/// One declared dimension of the graph's input.
#[derive(Clone, Debug, PartialEq)]
enum Dim {
    Fixed(i64),
    Param(String),
    Unknown,
}

impl std::fmt::Display for Dim {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Dim::Fixed(v) => write!(f, "{v}"),
            Dim::Param(p) => f.write_str(p),
            Dim::Unknown => f.write_str("?"),
        }
    }
}

fn shape_string(dims: &[Dim]) -> String {
    let parts: Vec<String> = dims.iter().map(Dim::to_string).collect();
    format!("[{}]", parts.join(", "))
}

/// A loaded, checked and optimised ONNX policy.
pub struct OnnxPolicy {
    spec: PolicySpec,
    layout: InputLayout,
    input_name: String,
    output_name: String,
    /// The batch the graph is fixed at, when it could not be made symbolic.
    fixed_batch: Option<usize>,
    plan: Arc<TypedRunnableModel>,
}

impl std::fmt::Debug for OnnxPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxPolicy")
            .field("spec", &self.spec)
            .field("layout", &self.layout)
            .field("input", &self.input_name)
            .field("output", &self.output_name)
            .field("fixed_batch", &self.fixed_batch)
            .finish_non_exhaustive()
    }
}

/// What the proto declares about the policy's input and output.
struct Declared {
    input_name: String,
    output_name: String,
    layout: InputLayout,
    batch: Dim,
}

fn tract_message(e: &TractError) -> String {
    format!("{e:#}")
}

/// Check the graph's single input and output against `spec` (as far as the proto declares them).
fn inspect(proto: &pb::ModelProto, spec: &PolicySpec) -> Result<Declared, PolicyError> {
    let Some(graph) = proto.graph.as_ref() else {
        return Err(PolicyError::Parse {
            len: 0,
            message: "the model has no graph".into(),
        });
    };
    let initializers: HashSet<&str> = graph.initializer.iter().map(|t| t.name.as_str()).collect();
    let inputs: Vec<&pb::ValueInfoProto> = graph
        .input
        .iter()
        .filter(|i| !initializers.contains(i.name.as_str()))
        .collect();
    if inputs.len() != 1 || graph.output.len() != 1 {
        return Err(PolicyError::Arity {
            inputs: inputs.len(),
            outputs: graph.output.len(),
        });
    }
    let input = inputs[0];
    let expected = format!(
        "[batch, {}, {}] (or flat [batch, {}])",
        spec.history,
        spec.obs_dim,
        spec.input_width()
    );
    let tensor = input
        .r#type
        .as_ref()
        .and_then(|t| t.value.as_ref())
        .map(|pb::type_proto::Value::TensorType(t)| t);
    let mut layout = InputLayout::Stacked;
    let mut batch = Dim::Unknown;
    if let Some(tensor) = tensor {
        if tensor.elem_type != ONNX_FLOAT {
            return Err(PolicyError::InputType {
                name: input.name.clone(),
                elem_type: tensor.elem_type,
            });
        }
        if let Some(shape) = tensor.shape.as_ref() {
            let dims: Vec<Dim> = shape
                .dim
                .iter()
                .map(|d| match &d.value {
                    Some(DimValue::DimValue(v)) => Dim::Fixed(*v),
                    Some(DimValue::DimParam(p)) if !p.is_empty() => Dim::Param(p.clone()),
                    _ => Dim::Unknown,
                })
                .collect();
            // A fixed inner dim must match; a symbolic or unknown one is pinned by our fact.
            let fits = |d: &Dim, want: usize| !matches!(d, Dim::Fixed(v) if *v != want as i64);
            let ok = match dims.len() {
                3 => {
                    layout = InputLayout::Stacked;
                    fits(&dims[1], spec.history) && fits(&dims[2], spec.obs_dim)
                }
                2 => {
                    layout = InputLayout::Flat;
                    fits(&dims[1], spec.input_width())
                }
                _ => false,
            };
            if !ok || matches!(dims.first(), Some(Dim::Fixed(v)) if *v < 1) {
                return Err(PolicyError::InputShape {
                    name: input.name.clone(),
                    got: shape_string(&dims),
                    expected,
                });
            }
            batch = dims[0].clone();
        }
    }
    Ok(Declared {
        input_name: input.name.clone(),
        output_name: graph.output[0].name.clone(),
        layout,
        batch,
    })
}

/// The input fact for `batch` (a symbol or a number).
fn input_fact(spec: &PolicySpec, layout: InputLayout, batch: TDim) -> InferenceFact {
    let dims: Vec<TDim> = match layout {
        InputLayout::Stacked => vec![batch, spec.history.into(), spec.obs_dim.into()],
        InputLayout::Flat => vec![batch, spec.input_width().into()],
    };
    f32::fact(dims).into()
}

/// Type, optimise and plan the graph with `fact` as its input; check the output is
/// `[batch, num_actions]`.
fn build(
    proto: &pb::ModelProto,
    spec: &PolicySpec,
    declared: &Declared,
    batch: Option<usize>,
) -> Result<Arc<TypedRunnableModel>, PolicyError> {
    let framework = tract_onnx::onnx()
        .with_ignore_output_shapes(true)
        .with_ignore_value_info(true);
    let model = framework
        .model_for_proto_model(proto)
        .map_err(|e| PolicyError::Build {
            stage: "translating the ONNX graph",
            message: tract_message(&e),
        })?;
    let batch_dim: TDim = match (batch, &declared.batch) {
        (Some(b), _) => b.into(),
        // The symbol must carry the dim_param's name, or tract sees two different batches.
        (None, Dim::Param(name)) => model.symbols.sym(name).into(),
        (None, _) => model.symbols.sym(DEFAULT_BATCH_SYMBOL).into(),
    };
    let model = model
        .with_input_fact(0, input_fact(spec, declared.layout, batch_dim.clone()))
        .and_then(|m| m.with_output_fact(0, InferenceFact::default()))
        .map_err(|e| PolicyError::Build {
            stage: "setting the input shape",
            message: tract_message(&e),
        })?;
    let typed = model.into_optimized().map_err(|e| PolicyError::Build {
        stage: "analysing and optimising",
        message: tract_message(&e),
    })?;
    let out = typed.output_fact(0).map_err(|e| PolicyError::Build {
        stage: "reading the output",
        message: tract_message(&e),
    })?;
    let shape: Vec<TDim> = out.shape.iter().cloned().collect();
    let expected = format!("[batch, {}] f32", spec.num_actions);
    let got = format!(
        "[{}] {:?}",
        shape
            .iter()
            .map(|d| d.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        out.datum_type
    );
    let actions_ok = shape.len() == 2
        && shape[1].as_i64() == Some(spec.num_actions as i64)
        && out.datum_type == f32::datum_type();
    if !actions_ok {
        return Err(PolicyError::OutputShape {
            name: declared.output_name.clone(),
            got,
            expected,
        });
    }
    if shape[0] != batch_dim {
        return Err(PolicyError::Build {
            stage: "checking the output batch",
            message: format!("output shape {got} does not follow the input batch {batch_dim}"),
        });
    }
    typed.into_runnable().map_err(|e| PolicyError::Build {
        stage: "planning",
        message: tract_message(&e),
    })
}

impl OnnxPolicy {
    /// Load a policy from ONNX bytes and check it against `spec`.
    pub fn from_bytes(bytes: &[u8], spec: PolicySpec) -> Result<Self, PolicyError> {
        let proto = tract_onnx::onnx()
            .proto_model_for_read(&mut &bytes[..])
            .map_err(|e| PolicyError::Parse {
                len: bytes.len(),
                message: tract_message(&e),
            })?;
        let declared = inspect(&proto, &spec).map_err(|e| match e {
            PolicyError::Parse { message, .. } => PolicyError::Parse {
                len: bytes.len(),
                message,
            },
            other => other,
        })?;
        let (plan, fixed_batch) = match build(&proto, &spec, &declared, None) {
            Ok(plan) => (plan, None),
            // Shape errors are final; a graph that only works at its exported batch (a
            // hard-coded Reshape, say) runs in chunks of that batch.
            Err(e @ PolicyError::OutputShape { .. }) => return Err(e),
            Err(e) => match declared.batch {
                Dim::Fixed(b) if b >= 1 => {
                    let b = b as usize;
                    tracing::warn!(
                        error = %e,
                        batch = b,
                        "policy batch cannot be made symbolic; running in chunks of its fixed batch"
                    );
                    (build(&proto, &spec, &declared, Some(b))?, Some(b))
                }
                _ => return Err(e),
            },
        };
        Ok(Self {
            spec,
            layout: declared.layout,
            input_name: declared.input_name,
            output_name: declared.output_name,
            fixed_batch,
            plan,
        })
    }

    /// Load a policy from an ONNX file and check it against `spec`.
    pub fn from_path(path: impl AsRef<Path>, spec: PolicySpec) -> Result<Self, PolicyError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path).map_err(|source| PolicyError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_bytes(&bytes, spec)
    }

    /// How the graph takes the history.
    pub fn layout(&self) -> InputLayout {
        self.layout
    }

    /// Name of the graph's input.
    pub fn input_name(&self) -> &str {
        &self.input_name
    }

    /// Name of the graph's output.
    pub fn output_name(&self) -> &str {
        &self.output_name
    }

    /// The batch the graph is stuck at (it then runs in chunks of it), or None when symbolic.
    pub fn fixed_batch(&self) -> Option<usize> {
        self.fixed_batch
    }

    /// Run one chunk of exactly the plan's batch.
    fn run_chunk(&self, history: &[f32], batch: usize, out: &mut [f32]) -> Result<(), PolicyError> {
        let s = &self.spec;
        let shape: Vec<usize> = match self.layout {
            InputLayout::Stacked => vec![batch, s.history, s.obs_dim],
            InputLayout::Flat => vec![batch, s.input_width()],
        };
        let mut run = || -> TractResult<()> {
            let input = Tensor::from_shape(&shape, history)?;
            let outputs = self.plan.run(tvec!(input.into()))?;
            let view = outputs[0].to_plain_array_view::<f32>()?;
            if view.len() != out.len() {
                return Err(TractError::msg(format!(
                    "output has {} values, expected {}",
                    view.len(),
                    out.len()
                )));
            }
            for (o, v) in out.iter_mut().zip(view.iter()) {
                *o = *v;
            }
            Ok(())
        };
        run().map_err(|e| PolicyError::Run(tract_message(&e)))
    }
}

impl Policy for OnnxPolicy {
    fn spec(&self) -> PolicySpec {
        self.spec
    }

    fn act(&self, history: &[f32], batch: usize, actions: &mut [f32]) -> Result<(), PolicyError> {
        let s = self.spec;
        s.check_batch(history, batch)?;
        if actions.len() != batch * s.num_actions {
            return Err(PolicyError::Batch {
                got: actions.len(),
                expected: batch * s.num_actions,
                detail: format!("action buffer [{batch}, {}]", s.num_actions),
            });
        }
        if batch == 0 {
            return Ok(());
        }
        let (w, a) = (s.input_width(), s.num_actions);
        match self.fixed_batch {
            None => self.run_chunk(history, batch, actions)?,
            Some(b) => {
                let mut padded = vec![0.0; b * w];
                let mut out = vec![0.0; b * a];
                for (hist, act) in history.chunks(b * w).zip(actions.chunks_mut(b * a)) {
                    padded[..hist.len()].copy_from_slice(hist);
                    padded[hist.len()..].fill(0.0);
                    self.run_chunk(&padded, b, &mut out)?;
                    act.copy_from_slice(&out[..act.len()]);
                }
            }
        }
        if let Some(i) = actions.iter().position(|v| !v.is_finite()) {
            return Err(PolicyError::NonFinite {
                env: i / a,
                joint: i % a,
                value: actions[i],
            });
        }
        Ok(())
    }
}
