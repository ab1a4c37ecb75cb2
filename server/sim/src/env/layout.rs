//! The published layout of every per-env tensor a step produces: names, shapes, element types and
//! named slices, derived from the observation tables (never written twice).

use crate::robot::NUM_JOINTS;
use crate::task::{Field, LABELS, OBSERVATION, PRIVILEGED, RewardTerm};

/// Element type of a tensor.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ElementType {
    /// 32-bit float.
    F32,
    /// Unsigned byte (flags, modes).
    U8,
    /// 32-bit unsigned integer.
    U32,
}

/// A named slice of a per-env vector.
#[derive(Clone, Debug, PartialEq)]
pub struct SliceLayout {
    /// Name.
    pub name: String,
    /// Offset in the row.
    pub offset: usize,
    /// Number of values.
    pub size: usize,
    /// Meaning and unit.
    pub doc: String,
}

/// One per-env tensor.
#[derive(Clone, Debug, PartialEq)]
pub struct TensorLayout {
    /// Name, as in the step results.
    pub name: &'static str,
    /// Shape of one env's row (empty: one value per env).
    pub row_shape: Vec<usize>,
    /// Element type.
    pub element: ElementType,
    /// Named slices of the row.
    pub slices: Vec<SliceLayout>,
    /// Meaning.
    pub doc: &'static str,
}

fn slices(table: &[Field]) -> Vec<SliceLayout> {
    let mut offset = 0;
    table
        .iter()
        .map(|f| {
            let s = SliceLayout {
                name: f.name.into(),
                offset,
                size: f.dim,
                doc: f.doc.into(),
            };
            offset += f.dim;
            s
        })
        .collect()
}

fn table_tensor(name: &'static str, table: &[Field], doc: &'static str) -> TensorLayout {
    let s = slices(table);
    let dim = s.iter().map(|x| x.size).sum();
    TensorLayout {
        name,
        row_shape: vec![dim],
        element: ElementType::F32,
        slices: s,
        doc,
    }
}

/// Every tensor of a step result.
pub fn tensor_layouts() -> Vec<TensorLayout> {
    let scalar = |name, element, doc| TensorLayout {
        name,
        row_shape: vec![],
        element,
        slices: vec![],
        doc,
    };
    let terms = RewardTerm::ALL
        .iter()
        .enumerate()
        .map(|(i, t)| SliceLayout {
            name: t.name().into(),
            offset: i,
            size: 1,
            doc: format!("{:?} term", t.group()),
        })
        .collect();
    vec![
        table_tensor(
            "obs",
            &OBSERVATION,
            "o_t, scaled and noised (after autoreset)",
        ),
        table_tensor("labels", &LABELS, "e_t, estimator labels (SI units)"),
        table_tensor(
            "privileged",
            &PRIVILEGED,
            "s_t, the env's randomised physical values",
        ),
        scalar("reward", ElementType::F32, "total reward"),
        TensorLayout {
            name: "reward_terms",
            row_shape: vec![RewardTerm::COUNT],
            element: ElementType::F32,
            slices: terms,
            doc: "weighted reward per term (weight x policy dt x mask x term)",
        },
        scalar(
            "terminated",
            ElementType::U8,
            "1: episode ended by trunk contact or physics blow-up",
        ),
        scalar("truncated", ElementType::U8, "1: episode ended by time-out"),
        scalar(
            "final_env_ids",
            ElementType::U32,
            "envs that ended this step (K rows)",
        ),
        table_tensor(
            "final_obs",
            &OBSERVATION,
            "last o_t of each ended episode (K rows)",
        ),
        table_tensor(
            "final_labels",
            &LABELS,
            "last e_t of each ended episode (K rows)",
        ),
        table_tensor(
            "final_privileged",
            &PRIVILEGED,
            "s_t of each ended episode (K rows)",
        ),
        scalar(
            "final_episode_length",
            ElementType::U32,
            "length in steps of each ended episode (K rows)",
        ),
        scalar(
            "mode",
            ElementType::U8,
            "task mode for the next action: 1 biped, 2 quad",
        ),
        scalar(
            "terrain_level",
            ElementType::U32,
            "terrain difficulty level",
        ),
        TensorLayout {
            name: "mode_levels",
            row_shape: vec![2],
            element: ElementType::U32,
            slices: vec![],
            doc: "each env's own level per mode (quad, biped); both terrain_level unless the \
                  curriculum keeps a level per mode",
        },
        TensorLayout {
            name: "actions",
            row_shape: vec![NUM_JOINTS],
            element: ElementType::F32,
            slices: vec![],
            doc: "input: joint target = default + action_scale * action",
        },
    ]
}
