//! How a robot is drawn: its collision shapes, coloured by link group, under one env's
//! entity paths.

use rerun::{
    Boxes3D, Capsules3D, Color, Ellipsoids3D, FillMode, Quaternion, RecordingStream, Transform3D,
};
use unigait_sim::robot::{ColliderRole, RobotModel, Shape};

use crate::entity;
use crate::error::{RecordError, log_err};

/// Entity paths of one recorded env's 3D scene.
#[derive(Clone, Debug)]
pub(crate) struct ScenePaths {
    pub(crate) robot: String,
    pub(crate) feet: String,
    pub(crate) terrain: String,
}

impl ScenePaths {
    pub(crate) fn followed() -> Self {
        Self {
            robot: entity::ROBOT.into(),
            feet: entity::FEET.into(),
            terrain: entity::TERRAIN.into(),
        }
    }

    pub(crate) fn other(index: usize) -> Self {
        let root = entity::other_env(index);
        Self {
            robot: format!("{root}/robot"),
            feet: format!("{root}/feet"),
            terrain: format!("{root}/terrain"),
        }
    }

    pub(crate) fn body(&self, name: &str) -> String {
        format!("{}/{name}", self.robot)
    }
}

/// A rotation as rerun's quaternion (plain xyzw arrays in between: rapier and rerun use
/// different glam versions).
pub(crate) fn quat(q: impl Into<[f32; 4]>) -> Quaternion {
    Quaternion::from_xyzw(q.into())
}

/// Colour of a collider by link group: trunk and head blue, hips grey, thighs and calves by
/// side (left warm, right cool, so diagonal leg pairs of a trot read), feet near black.
fn link_color(body: &str, role: ColliderRole) -> Color {
    let left = body.starts_with("FL") || body.starts_with("RL");
    match role {
        ColliderRole::Trunk => Color::from_rgb(60, 90, 150),
        ColliderRole::Head => Color::from_rgb(95, 130, 190),
        ColliderRole::Foot(_) => Color::from_rgb(35, 35, 35),
        ColliderRole::Penalised | ColliderRole::Other => {
            if body.ends_with("_hip") {
                Color::from_rgb(115, 115, 120)
            } else if body.ends_with("_thigh") {
                if left {
                    Color::from_rgb(225, 135, 50)
                } else {
                    Color::from_rgb(40, 155, 165)
                }
            } else if body.ends_with("_calf") {
                if left {
                    Color::from_rgb(240, 185, 120)
                } else {
                    Color::from_rgb(120, 205, 210)
                }
            } else {
                Color::from_rgb(150, 150, 150)
            }
        }
    }
}

/// The robot's collision shapes under `paths.robot`, static in their bodies' frames.
pub(crate) fn log_robot_shapes(
    rec: &RecordingStream,
    model: &RobotModel,
    paths: &ScenePaths,
) -> Result<(), RecordError> {
    for body in &model.bodies {
        for (k, c) in body.colliders.iter().enumerate() {
            let path = format!("{}/geom{k}", paths.body(&body.name));
            let o = &c.geometry.origin;
            rec.log_static(
                path.as_str(),
                &Transform3D::from_translation_rotation(
                    [o.translation.x, o.translation.y, o.translation.z],
                    quat(o.rotation),
                ),
            )
            .map_err(log_err)?;
            let color = link_color(&body.name, c.role);
            match c.geometry.shape {
                Shape::Box { size } => rec.log_static(
                    path.as_str(),
                    &Boxes3D::from_half_sizes([[size.x / 2.0, size.y / 2.0, size.z / 2.0]])
                        .with_colors([color])
                        .with_fill_mode(FillMode::Solid),
                ),
                // The physics makes cylinders capsules (legged_gym's choice): draw those.
                // rerun's capsule runs from z = 0 to z = length; ours is centred.
                Shape::Cylinder { radius, length } => rec.log_static(
                    path.as_str(),
                    &Capsules3D::from_lengths_and_radii([length], [radius])
                        .with_translations([[0.0, 0.0, -length / 2.0]])
                        .with_colors([color])
                        .with_fill_mode(FillMode::Solid),
                ),
                Shape::Sphere { radius } => rec.log_static(
                    path.as_str(),
                    &Ellipsoids3D::from_radii([radius])
                        .with_colors([color])
                        .with_fill_mode(FillMode::Solid),
                ),
            }
            .map_err(log_err)?;
        }
    }
    Ok(())
}

/// The robot's drawing alone, as `.rrd` bytes: its collision shapes, static, at
/// `robot/<body>/geom<k>` (the shapes and colours of every recording). A live view re-roots it
/// under an env's entity and poses `.../robot/<body>` itself (`Spec.robot_drawing_rrd`).
pub fn robot_drawing_rrd(model: &RobotModel) -> Result<Vec<u8>, RecordError> {
    let (rec, storage) = rerun::RecordingStreamBuilder::new(crate::APPLICATION_ID)
        .send_properties(false)
        .memory()
        .map_err(crate::error::open_err)?;
    let paths = ScenePaths {
        robot: "robot".into(),
        feet: "feet".into(),
        terrain: "terrain".into(),
    };
    log_robot_shapes(&rec, model, &paths)?;
    rec.flush_blocking().map_err(log_err)?;
    let bytes = storage.drain_as_bytes().map_err(log_err)?;
    rec.disconnect();
    Ok(bytes)
}
