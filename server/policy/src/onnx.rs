//! ONNX policies run with tract: load, check the shapes, make the batch symbolic, run batched.
//!
//! tract plans a graph much better when every shape is known (kernels, tiling and packing are
//! chosen per size; the symbolic-batch plan was ~1.4x slower on the paper network at batch
//! 4096), so the symbolic graph is only the template: the first call at a given row count
//! builds an optimised plan for exactly that count and caches it. Large batches run in chunks
//! of [`OnnxPolicy::CHUNK_ROWS`] rows, so one cached plan serves every large batch and each
//! layer's activations stay in cache between one matmul and the next.

use std::collections::{HashMap, HashSet};
use std::path::Path;
use std::sync::{Arc, Mutex};

use tract_onnx::pb;
use tract_onnx::pb::tensor_shape_proto::dimension::Value as DimValue;
use tract_onnx::prelude::*;

use crate::checks::{ModelLimits, parse_checked};
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

/// The decluttered graph with a symbolic batch: the template concrete plans are made from.
struct Template {
    model: TypedModel,
    batch: Symbol,
}

/// A loaded, checked and optimised ONNX policy.
pub struct OnnxPolicy {
    spec: PolicySpec,
    layout: InputLayout,
    input_name: String,
    output_name: String,
    /// The batch the graph is fixed at, when it could not be made symbolic.
    fixed_batch: Option<usize>,
    /// The plan for any batch (symbolic), or for the fixed batch.
    plan: Arc<TypedRunnableModel>,
    /// None when the batch is fixed (the plan is concrete already).
    template: Option<Template>,
    /// Plans optimised for one row count, built on first use. Behind a mutex so `act` stays
    /// `&self` and the policy `Sync`; the lock is only held to look up or insert.
    plans: Mutex<HashMap<usize, Arc<TypedRunnableModel>>>,
}

impl std::fmt::Debug for OnnxPolicy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OnnxPolicy")
            .field("spec", &self.spec)
            .field("layout", &self.layout)
            .field("input", &self.input_name)
            .field("output", &self.output_name)
            .field("fixed_batch", &self.fixed_batch)
            .field("cached_plans", &self.cached_plan_sizes())
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

/// Type and declutter the graph with a `batch`-row input (the declared batch symbol when None);
/// check the output is `[batch, num_actions]`. Returns the model and its batch dim.
fn typed(
    proto: &pb::ModelProto,
    spec: &PolicySpec,
    declared: &Declared,
    batch: Option<usize>,
) -> Result<(TypedModel, TDim), PolicyError> {
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
    let typed = model
        .into_typed()
        .and_then(|m| m.into_decluttered())
        .map_err(|e| PolicyError::Build {
            stage: "analysing and optimising",
            message: tract_message(&e),
        })?;
    // Here, so every plan made from this model (symbolic or concrete) has it. An optimisation
    // only: on a failure (a half-patched copy is dropped) the expansion runs as it is.
    let mut fused = typed.clone();
    let typed = match crate::elu::fuse_elu(&mut fused) {
        Ok(_) => fused,
        Err(e) => {
            tracing::warn!(error = %tract_message(&e), "cannot fuse the ELU activations");
            typed
        }
    };
    check_output(&typed, spec, &declared.output_name, &batch_dim)?;
    Ok((typed, batch_dim))
}

/// Check the model's output is `[batch, num_actions]` f32.
fn check_output(
    model: &TypedModel,
    spec: &PolicySpec,
    output_name: &str,
    batch_dim: &TDim,
) -> Result<(), PolicyError> {
    let out = model.output_fact(0).map_err(|e| PolicyError::Build {
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
            name: output_name.to_string(),
            got,
            expected,
        });
    }
    if shape[0] != *batch_dim {
        return Err(PolicyError::Build {
            stage: "checking the output batch",
            message: format!("output shape {got} does not follow the input batch {batch_dim}"),
        });
    }
    Ok(())
}

/// Optimise a typed model (kernel selection, packing) and plan it.
fn plan(model: TypedModel) -> Result<Arc<TypedRunnableModel>, PolicyError> {
    model
        .into_optimized()
        .map_err(|e| PolicyError::Build {
            stage: "optimising",
            message: tract_message(&e),
        })?
        .into_runnable()
        .map_err(|e| PolicyError::Build {
            stage: "planning",
            message: tract_message(&e),
        })
}

/// The template with its batch symbol bound to `rows`, optimised and planned.
fn concrete_plan(
    template: &Template,
    spec: &PolicySpec,
    output_name: &str,
    rows: usize,
) -> Result<Arc<TypedRunnableModel>, PolicyError> {
    let rows_dim = TDim::Val(rows as i64);
    let subs = HashMap::from([(template.batch.clone(), rows_dim.clone())]);
    let model = template
        .model
        .set_symbols(&subs)
        .map_err(|e| PolicyError::Build {
            stage: "fixing the batch",
            message: tract_message(&e),
        })?;
    check_output(&model, spec, output_name, &rows_dim)?;
    plan(model)
}

impl OnnxPolicy {
    /// Rows per plan run for large batches. Measured on the paper network at batch 4096 (Zen 4,
    /// one thread, median CPU ms per call over 4-5 rounds): 128 rows 45, 192 rows 45-48, 256 rows
    /// 38-42, 384 rows 42-43, 512 rows 41-42, 768-1024 rows 42-46, the whole 4096 at once 45-47.
    /// At 256 rows a layer's activations (at most 256 x 512 f32, 512 KiB) stay in L2 from one
    /// matmul to the next, and a run is still long enough that its fixed cost is lost.
    pub const CHUNK_ROWS: usize = 256;

    /// Concrete plans kept per policy (chunk size, remainders, small batches). A caller cycling
    /// through more distinct row counts than this gets the symbolic plan for the extra ones
    /// rather than an unbounded cache or a rebuild (~10 ms) on every call.
    pub const MAX_CACHED_PLANS: usize = 16;

    /// Load a policy from ONNX bytes and check it against `spec`.
    pub fn from_bytes(bytes: &[u8], spec: PolicySpec) -> Result<Self, PolicyError> {
        let proto = tract_onnx::onnx()
            .proto_model_for_read(&mut &bytes[..])
            .map_err(|e| PolicyError::Parse {
                len: bytes.len(),
                message: tract_message(&e),
            })?;
        Self::from_proto(&proto, bytes.len(), spec)
    }

    /// Load an untrusted policy: check its size, ops and constants against `limits` (see
    /// [`crate::ALLOWED_OPS`]) before tract analyses it. Run it in a worker process with memory
    /// and time limits ([`crate::SandboxedPolicy`]): allowed ops can still fold into large
    /// tensors.
    pub fn from_untrusted_bytes(
        bytes: &[u8],
        spec: PolicySpec,
        limits: &ModelLimits,
    ) -> Result<Self, PolicyError> {
        let proto = parse_checked(bytes, limits)?;
        Self::from_proto(&proto, bytes.len(), spec)
    }

    fn from_proto(
        proto: &pb::ModelProto,
        len: usize,
        spec: PolicySpec,
    ) -> Result<Self, PolicyError> {
        let declared = inspect(proto, &spec).map_err(|e| match e {
            PolicyError::Parse { message, .. } => PolicyError::Parse { len, message },
            other => other,
        })?;
        let symbolic = typed(proto, &spec, &declared, None).and_then(|(model, batch)| {
            let TDim::Sym(batch) = batch else {
                return Err(PolicyError::Build {
                    stage: "setting the input shape",
                    message: format!("the batch dim {batch} is not a symbol"),
                });
            };
            let plan = plan(model.clone())?;
            Ok((plan, Template { model, batch }))
        });
        let (plan, template, fixed_batch) = match symbolic {
            Ok((plan, template)) => (plan, Some(template), None),
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
                    let (model, _) = typed(proto, &spec, &declared, Some(b))?;
                    (plan(model)?, None, Some(b))
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
            template,
            plans: Mutex::new(HashMap::new()),
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

    /// Row counts that have a cached concrete plan, ascending.
    pub fn cached_plan_sizes(&self) -> Vec<usize> {
        let mut sizes: Vec<usize> = self.lock_plans().keys().copied().collect();
        sizes.sort_unstable();
        sizes
    }

    fn lock_plans(&self) -> std::sync::MutexGuard<'_, HashMap<usize, Arc<TypedRunnableModel>>> {
        // The map is valid whatever a panicking holder was doing: it only ever gains entries.
        self.plans.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The plan for exactly `rows` rows: the cached concrete one, built now on first use, or the
    /// symbolic one when the cache is full or the concrete build failed.
    fn plan_for(&self, rows: usize) -> Arc<TypedRunnableModel> {
        let Some(template) = &self.template else {
            return self.plan.clone();
        };
        {
            let plans = self.lock_plans();
            if let Some(plan) = plans.get(&rows) {
                return plan.clone();
            }
            if plans.len() >= Self::MAX_CACHED_PLANS {
                return self.plan.clone();
            }
        }
        // Built without the lock, so other threads (and other sizes) are not held up; two
        // threads racing on the same size both build and the first insert wins.
        let plan = match concrete_plan(template, &self.spec, &self.output_name, rows) {
            Ok(plan) => plan,
            Err(e) => {
                // The symbolic plan is correct at any batch, only slower; remember it for this
                // size so the failing build is not retried on every call.
                tracing::warn!(error = %e, rows, "no concrete-batch plan; using the symbolic one");
                self.plan.clone()
            }
        };
        self.lock_plans().entry(rows).or_insert(plan).clone()
    }

    /// Run one chunk of `batch` rows through `plan` (symbolic, or concrete at `batch`).
    fn run_chunk(
        &self,
        plan: &Arc<TypedRunnableModel>,
        history: &[f32],
        batch: usize,
        out: &mut [f32],
    ) -> Result<(), PolicyError> {
        let s = &self.spec;
        let shape: Vec<usize> = match self.layout {
            InputLayout::Stacked => vec![batch, s.history, s.obs_dim],
            InputLayout::Flat => vec![batch, s.input_width()],
        };
        let mut run = || -> TractResult<()> {
            // tract owns its (aligned) input buffer, hence one copy in; the result is copied
            // straight out of the output tensor, without an intermediate array or clone.
            let input = Tensor::from_shape(&shape, history)?;
            let outputs = plan.run(tvec!(input.into()))?;
            let values = outputs[0].try_as_plain_ram()?;
            let values = values.as_slice::<f32>()?;
            if values.len() != out.len() {
                return Err(TractError::msg(format!(
                    "output has {} values, expected {}",
                    values.len(),
                    out.len()
                )));
            }
            out.copy_from_slice(values);
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
        s.check_call(history, batch, actions)?;
        if batch == 0 {
            return Ok(());
        }
        let (w, a) = (s.input_width(), s.num_actions);
        match self.fixed_batch {
            None => {
                for start in (0..batch).step_by(Self::CHUNK_ROWS) {
                    let rows = Self::CHUNK_ROWS.min(batch - start);
                    let hist = &history[start * w..(start + rows) * w];
                    let act = &mut actions[start * a..(start + rows) * a];
                    self.run_chunk(&self.plan_for(rows), hist, rows, act)?;
                }
            }
            Some(b) => {
                let mut padded = vec![0.0; b * w];
                let mut out = vec![0.0; b * a];
                for (hist, act) in history.chunks(b * w).zip(actions.chunks_mut(b * a)) {
                    padded[..hist.len()].copy_from_slice(hist);
                    padded[hist.len()..].fill(0.0);
                    self.run_chunk(&self.plan, &padded, b, &mut out)?;
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
