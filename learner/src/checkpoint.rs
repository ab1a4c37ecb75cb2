//! Checkpoints: the networks with their parameter ids, both Adam states (burn's optimiser
//! record), the counters, the learning rate and the generators' states, so that a resumed run
//! continues exactly where the saved one was.
//!
//! One file: the magic `UGLCKPT1`, a little-endian u64 header length, a JSON header, then the
//! blobs the header points into (f32 little-endian weights, the optimiser records).

use std::io::Write;
use std::path::Path;

use burn::module::{Module, ModuleMapper, ModuleVisitor, Param, ParamId};
use burn::prelude::*;
use serde::{Deserialize, Serialize};

use crate::env::Dims;
use crate::{Error, Result};

const MAGIC: &[u8; 8] = b"UGLCKPT1";

/// One parameter tensor in the file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TensorEntry {
    /// burn's parameter id (the optimiser's state is keyed by it).
    pub id: u64,
    /// Its shape.
    pub shape: Vec<usize>,
    /// Byte offset of its f32 values in the blob section.
    pub offset: usize,
}

/// A byte range of the blob section.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct Blob {
    /// Offset.
    pub offset: usize,
    /// Length.
    pub len: usize,
}

/// What a checkpoint's header holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// Iterations trained.
    pub iteration: u64,
    /// Env steps trained.
    pub total_env_steps: u64,
    /// PPO's learning rate (the adaptive schedule's state).
    pub learning_rate: f64,
    /// The action-noise generator's state.
    pub action_rng: u64,
    /// The shuffles' generator's state.
    pub update_rng: u64,
    /// The config the networks trained with, as TOML.
    pub config_toml: String,
    /// The spec's sizes.
    pub dims: Dims,
    /// Where the networks come from (recipe, stage).
    pub provenance: serde_json::Value,
    /// The upright indicator's threshold at the last rollout's end.
    pub upright_pitch: Option<f32>,
    /// Each env's terrain level at the last rollout's end.
    pub terrain_levels: Vec<u32>,
    /// Each env's (quad, biped) levels at the last rollout's end (decision record 0036; empty
    /// in checkpoints written before they were recorded).
    #[serde(default)]
    pub terrain_mode_levels: Vec<u32>,
    /// The physics engine the session trained on, as its spec named it ("" in checkpoints
    /// written before it was recorded: see [`Header::trained_engine`]).
    #[serde(default)]
    pub physics_engine: String,
    /// The actor-critic's parameters, in visiting order.
    pub actor_critic: Vec<TensorEntry>,
    /// The estimator's parameters, in visiting order.
    pub estimator: Vec<TensorEntry>,
    /// PPO's Adam record.
    pub ppo_optimizer: Blob,
    /// The estimator's Adam record.
    pub estimator_optimizer: Blob,
}

impl Header {
    /// The physics engine these networks trained on: the one recorded, else the task's choice,
    /// else rapier (the default before it was recorded).
    pub fn trained_engine(&self) -> String {
        if !self.physics_engine.is_empty() {
            return self.physics_engine.clone();
        }
        let config = toml::from_str(&self.config_toml)
            .ok()
            .and_then(|t| crate::config::TrainConfig::from_table(t).ok());
        let task_choice = config.and_then(|c| c.task_engine().map(str::to_string));
        task_choice.unwrap_or_else(|| crate::config::ENGINE_BEFORE_RECORDING.into())
    }
}

/// A checkpoint in memory.
#[derive(Debug, Clone, PartialEq)]
pub struct Checkpoint {
    /// The header.
    pub header: Header,
    /// The blob section.
    pub blobs: Vec<u8>,
}

struct Collect<'a> {
    entries: Vec<TensorEntry>,
    blobs: &'a mut Vec<u8>,
    error: Option<Error>,
}

impl ModuleVisitor for Collect<'_> {
    fn visit_float<const D: usize>(&mut self, param: &Param<Tensor<D>>) {
        let t = param.val();
        let shape = t.dims().to_vec();
        match crate::nets::values(t) {
            Ok(v) => {
                self.entries.push(TensorEntry {
                    id: param.id.val(),
                    shape,
                    offset: self.blobs.len(),
                });
                for x in v {
                    self.blobs.extend_from_slice(&x.to_le_bytes());
                }
            }
            Err(e) => self.error = Some(e),
        }
    }
}

/// Append `module`'s parameters to `blobs`; their entries.
pub fn collect<M: Module>(module: &M, blobs: &mut Vec<u8>) -> Result<Vec<TensorEntry>> {
    let mut c = Collect {
        entries: Vec::new(),
        blobs,
        error: None,
    };
    module.visit(&mut c);
    match c.error {
        Some(e) => Err(e),
        None => Ok(c.entries),
    }
}

struct Restore<'a> {
    entries: &'a [TensorEntry],
    blobs: &'a [u8],
    next: usize,
    error: Option<String>,
}

impl ModuleMapper for Restore<'_> {
    fn map_float<const D: usize>(&mut self, param: Param<Tensor<D>>) -> Param<Tensor<D>> {
        let i = self.next;
        self.next += 1;
        let shape = param.val().dims().to_vec();
        let Some(entry) = self.entries.get(i) else {
            self.error = Some(format!(
                "the checkpoint has {} tensors, fewer than the network",
                self.entries.len()
            ));
            return param;
        };
        if entry.shape != shape {
            self.error = Some(format!(
                "tensor {i}: the checkpoint's shape {:?}, the network's {shape:?} (other network sizes?)",
                entry.shape
            ));
            return param;
        }
        let n: usize = shape.iter().product();
        let Some(bytes) = self.blobs.get(entry.offset..entry.offset + 4 * n) else {
            self.error = Some(format!("tensor {i} lies beyond the file's end"));
            return param;
        };
        let values: Vec<f32> = bytes
            .chunks_exact(4)
            .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
            .collect();
        let device = param.lazy_device();
        let tensor = Tensor::from_data(TensorData::new(values, shape), &device);
        param.transform_for_load(tensor, ParamId::from(entry.id))
    }
}

/// `module` with the values and parameter ids of `entries`.
pub fn restore<M: Module>(module: M, entries: &[TensorEntry], blobs: &[u8]) -> Result<M> {
    let mut r = Restore {
        entries,
        blobs,
        next: 0,
        error: None,
    };
    let module = module.map(&mut r);
    if let Some(e) = r.error {
        return Err(Error::Checkpoint(e));
    }
    if r.next != entries.len() {
        return Err(Error::Checkpoint(format!(
            "the checkpoint has {} tensors, the network {}",
            entries.len(),
            r.next
        )));
    }
    Ok(module)
}

impl Checkpoint {
    /// The bytes of blob `b`.
    pub fn blob(&self, b: Blob) -> Result<&[u8]> {
        self.blobs
            .get(b.offset..b.offset + b.len)
            .ok_or_else(|| Error::Checkpoint("a blob lies beyond the file's end".into()))
    }

    /// Write to `path` (through a temporary file, so an interrupted write leaves the old one).
    pub fn save(&self, path: &Path) -> Result<()> {
        let header = serde_json::to_vec(&self.header)
            .map_err(|e| Error::Checkpoint(format!("header: {e}")))?;
        let tmp = path.with_extension("partial");
        {
            let mut f = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
            f.write_all(MAGIC)?;
            f.write_all(&(header.len() as u64).to_le_bytes())?;
            f.write_all(&header)?;
            f.write_all(&self.blobs)?;
            f.flush()?;
        }
        std::fs::rename(&tmp, path)?;
        Ok(())
    }

    /// Read `path`.
    pub fn load(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path)?;
        let bad = |what: &str| Error::Checkpoint(format!("{}: {what}", path.display()));
        if bytes.len() < 16 || &bytes[..8] != MAGIC {
            return Err(bad("not a unigait-learner checkpoint"));
        }
        let mut len = [0u8; 8];
        len.copy_from_slice(&bytes[8..16]);
        let len = usize::try_from(u64::from_le_bytes(len)).map_err(|_| bad("header length"))?;
        let end = 16usize
            .checked_add(len)
            .filter(|&e| e <= bytes.len())
            .ok_or_else(|| bad("truncated header"))?;
        let header: Header =
            serde_json::from_slice(&bytes[16..end]).map_err(|e| bad(&format!("header: {e}")))?;
        Ok(Self {
            header,
            blobs: bytes[end..].to_vec(),
        })
    }
}
