//! Terrain selection from a session's config.

use std::sync::Arc;

use unigait_proto::v1::TerrainConfig;
use unigait_sim::terrain::Terrain;

use crate::error::ServiceError;

/// The terrain a session asked for, with its display name.
pub fn terrain_for(
    config: Option<&TerrainConfig>,
    _seed: u64,
) -> Result<(Arc<Terrain>, String), ServiceError> {
    let kind = config.map(|c| c.kind.as_str()).unwrap_or("");
    match kind {
        "" | "flat" => Ok((Arc::new(Terrain::Flat), "flat".into())),
        other => Err(ServiceError::InvalidArgument(format!(
            "unknown terrain kind `{other}`; known: flat"
        ))),
    }
}
