//! Terrain selection from a session's config.

use std::sync::Arc;

use unigait_proto::v1::TerrainConfig;
use unigait_sim::terrain::{Terrain, TerrainKind, TerrainSpec, TerrainType};

use crate::error::ServiceError;
use crate::limits::CostCaps;

/// Highest starting level of the curriculum when the config leaves it at 0 (legged_gym: 5).
const DEFAULT_MAX_INIT_LEVEL: u32 = 5;

/// The terrain a session of `num_envs` asked for, with its display name. The grid is generated
/// from the session seed, so sessions with the same config and seed see the same terrain. A grid
/// costlier than `caps` allows is refused before it is built.
pub fn terrain_for(
    config: Option<&TerrainConfig>,
    seed: u64,
    num_envs: usize,
    caps: &CostCaps,
) -> Result<(Arc<Terrain>, String), ServiceError> {
    let (kind, level) = config.map_or(("", 0), |c| (c.kind.as_str(), c.level));
    let initial_levels = config.map_or(&[][..], |c| c.initial_levels.as_slice());
    if !initial_levels.is_empty() && (kind != "curriculum" || initial_levels.len() != num_envs) {
        return Err(ServiceError::InvalidArgument(format!(
            "terrain.initial_levels: {} levels for a `{kind}` terrain of {num_envs} envs; they \
             are for \"curriculum\", one per env",
            initial_levels.len()
        )));
    }
    let mode_levels = config.map_or(&[][..], |c| c.initial_mode_levels.as_slice());
    if !mode_levels.is_empty() && (kind != "curriculum" || mode_levels.len() != 2 * num_envs) {
        return Err(ServiceError::InvalidArgument(format!(
            "terrain.initial_mode_levels: {} levels for a `{kind}` terrain of {num_envs} envs; \
             they are for \"curriculum\", two per env (quad, biped)",
            mode_levels.len()
        )));
    }
    let columns = config.map_or(&[][..], |c| c.columns.as_slice());
    let column_types = if columns.is_empty() {
        None
    } else {
        Some(column_types(kind, columns, caps)?)
    };
    let spec_kind = match kind {
        "" | "flat" => return Ok((Arc::new(Terrain::Flat), "flat".into())),
        "curriculum" => TerrainKind::Curriculum {
            max_init_level: if level == 0 {
                DEFAULT_MAX_INIT_LEVEL
            } else {
                level
            },
        },
        name => match TerrainType::from_name(name) {
            Some(terrain_type) => TerrainKind::Pinned {
                terrain_type,
                level,
            },
            None => {
                return Err(ServiceError::InvalidArgument(format!(
                    "unknown terrain kind `{name}`; known: flat, curriculum, {}",
                    type_names()
                )));
            }
        },
    };
    let mut spec = TerrainSpec {
        kind: spec_kind,
        ..TerrainSpec::default()
    };
    if let Some(types) = column_types {
        spec.types = types;
    }
    let mut terrain = Terrain::from_spec(&spec, seed)?;
    if !initial_levels.is_empty() {
        terrain = terrain.with_initial_levels(initial_levels.to_vec())?;
    }
    if !mode_levels.is_empty() {
        let pairs = mode_levels.chunks_exact(2).map(|p| [p[0], p[1]]).collect();
        terrain = terrain.with_initial_mode_levels(pairs)?;
    }
    let name = if kind == "curriculum" {
        "curriculum".to_string()
    } else {
        format!("{kind} level {level}")
    };
    Ok((Arc::new(terrain), name))
}

/// The column types a curriculum session named (`TerrainConfig.columns`).
fn column_types(
    kind: &str,
    columns: &[String],
    caps: &CostCaps,
) -> Result<Vec<TerrainType>, ServiceError> {
    if kind != "curriculum" {
        return Err(ServiceError::InvalidArgument(format!(
            "terrain.columns: {} columns for a `{kind}` terrain; they are for \"curriculum\"",
            columns.len()
        )));
    }
    if columns.len() > caps.max_terrain_columns {
        return Err(ServiceError::LimitExceeded(format!(
            "terrain.columns: {} columns, over this server's cap of {}",
            columns.len(),
            caps.max_terrain_columns
        )));
    }
    let types = columns
        .iter()
        .enumerate()
        .map(|(i, name)| {
            TerrainType::from_name(name).ok_or_else(|| {
                ServiceError::InvalidArgument(format!(
                    "terrain.columns[{i}]: unknown terrain type `{name}`; known: {}",
                    type_names()
                ))
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let rough = types
        .iter()
        .filter(|&&t| t == TerrainType::RoughSlope)
        .count();
    if rough > caps.max_rough_slope_columns {
        return Err(ServiceError::LimitExceeded(format!(
            "terrain.columns: {rough} rough_slope columns, over this server's cap of {} (each \
             keeps two mesh triangles per grid cell)",
            caps.max_rough_slope_columns
        )));
    }
    Ok(types)
}

/// The column types of `terrain`'s grid, by name (empty without a grid).
pub fn column_names(terrain: &Terrain) -> Vec<String> {
    terrain.grid().map_or_else(Vec::new, |grid| {
        grid.spec()
            .types
            .iter()
            .map(|t| t.name().to_string())
            .collect()
    })
}

/// Every terrain type's name, comma-separated (for the errors that list them).
fn type_names() -> String {
    let names: Vec<&str> = TerrainType::ALL.iter().map(|t| t.name()).collect();
    names.join(", ")
}
