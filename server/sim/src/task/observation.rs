//! The observation o_t, written once as a table (name, size, scale, noise); sizes, offsets, noise
//! and the published layout all derive from it.

/// One named slice of a flat per-env tensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Field {
    /// Name.
    pub name: &'static str,
    /// Number of values.
    pub dim: usize,
    /// Scale applied to the physical value, per value (len = dim).
    pub scale: &'static [f32],
    /// Noise amplitude in physical units, per value (value += U(-1,1) * level * noise * scale).
    pub noise: f32,
    /// Unit and meaning.
    pub doc: &'static str,
}

/// The observation table, in order (53 values).
pub const OBSERVATION: [Field; 9] = [
    Field {
        name: "cmd",
        dim: 3,
        scale: &[2.0, 2.0, 0.25],
        noise: 0.0,
        doc: "commands vx, vy (heading frame, m/s), wz (rad/s)",
    },
    Field {
        name: "phi",
        dim: 3,
        scale: &[1.0, 1.0, 1.0],
        noise: 0.05,
        doc: "orientation: gravity y in base frame (roll measure), Euler pitch (rad, + nose down), gravity z in base frame",
    },
    Field {
        name: "omega",
        dim: 3,
        scale: &[0.25; 3],
        noise: 0.2,
        doc: "base angular velocity, base frame (rad/s)",
    },
    Field {
        name: "q",
        dim: 12,
        scale: &[1.0; 12],
        noise: 0.01,
        doc: "joint angles minus defaults (rad)",
    },
    Field {
        name: "qdot",
        dim: 12,
        scale: &[0.05; 12],
        noise: 1.5,
        doc: "joint speeds (rad/s)",
    },
    Field {
        name: "last_action",
        dim: 12,
        scale: &[1.0; 12],
        noise: 0.0,
        doc: "previous action a_{t-1}",
    },
    Field {
        name: "mode",
        dim: 2,
        scale: &[1.0; 2],
        noise: 0.0,
        doc: "one-hot task mode (biped, quad)",
    },
    Field {
        name: "clock",
        dim: 4,
        scale: &[1.0; 4],
        noise: 0.0,
        doc: "sin(2 pi (Phi + theta_i)) per foot FL FR RL RR; rear 0 in biped mode",
    },
    Field {
        name: "ratio",
        dim: 2,
        scale: &[1.0; 2],
        noise: 0.0,
        doc: "swing ratio, stance ratio",
    },
];

/// The estimator labels e_t (14 values, SI units, unscaled).
pub const LABELS: [Field; 4] = [
    Field {
        name: "base_lin_vel",
        dim: 3,
        scale: &[1.0; 3],
        noise: 0.0,
        doc: "base linear velocity, base frame (m/s)",
    },
    Field {
        name: "foot_contact",
        dim: 4,
        scale: &[1.0; 4],
        noise: 0.0,
        doc: "1 if the foot's contact force > 1 N, FL FR RL RR",
    },
    Field {
        name: "terrain_normal",
        dim: 3,
        scale: &[1.0; 3],
        noise: 0.0,
        doc: "terrain normal under the base, base frame",
    },
    Field {
        name: "foot_height",
        dim: 4,
        scale: &[1.0; 4],
        noise: 0.0,
        doc: "foot sole height above the terrain (m)",
    },
];

/// The privileged critic extras s_t: the env's randomised physical values (10), each mapped
/// linearly from its Table V range to [-1, 1] so that a network sees them on one scale (raw, a
/// CoM offset spans +-0.01 m and a joint friction 0.005-0.01 next to a payload of +-1 kg).
pub const PRIVILEGED: [Field; 8] = [
    Field {
        name: "friction",
        dim: 1,
        scale: &[1.0],
        noise: 0.0,
        doc: "robot-terrain friction coefficient, mapped to [-1, 1] over its randomisation range",
    },
    Field {
        name: "payload",
        dim: 1,
        scale: &[1.0],
        noise: 0.0,
        doc: "payload on the trunk (kg), mapped to [-1, 1] over its randomisation range",
    },
    Field {
        name: "com_offset",
        dim: 3,
        scale: &[1.0; 3],
        noise: 0.0,
        doc: "trunk centre-of-mass shift (m), mapped to [-1, 1] over its randomisation range",
    },
    Field {
        name: "joint_damping",
        dim: 1,
        scale: &[1.0],
        noise: 0.0,
        doc: "joint viscous damping (N m s/rad), mapped to [-1, 1] over its randomisation range",
    },
    Field {
        name: "joint_friction",
        dim: 1,
        scale: &[1.0],
        noise: 0.0,
        doc: "joint Coulomb friction (N m), mapped to [-1, 1] over its randomisation range",
    },
    Field {
        name: "armature",
        dim: 1,
        scale: &[1.0],
        noise: 0.0,
        doc: "rotor inertia per joint (kg m^2), mapped to [-1, 1] over its randomisation range",
    },
    Field {
        name: "kp_factor",
        dim: 1,
        scale: &[1.0],
        noise: 0.0,
        doc: "factor on kp, mapped to [-1, 1] over its randomisation range",
    },
    Field {
        name: "kd_factor",
        dim: 1,
        scale: &[1.0],
        noise: 0.0,
        doc: "factor on kd, mapped to [-1, 1] over its randomisation range",
    },
];

/// Total size of a table.
pub const fn table_dim(table: &[Field]) -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < table.len() {
        n += table[i].dim;
        i += 1;
    }
    n
}

/// Size of o_t.
pub const OBS_DIM: usize = table_dim(&OBSERVATION);
/// Size of e_t.
pub const LABEL_DIM: usize = table_dim(&LABELS);
/// Size of s_t.
pub const PRIVILEGED_DIM: usize = table_dim(&PRIVILEGED);

/// Offset of the field `name` in `table`, with its size.
pub fn slice_of(table: &[Field], name: &str) -> Option<(usize, usize)> {
    let mut offset = 0;
    for f in table {
        if f.name == name {
            return Some((offset, f.dim));
        }
        offset += f.dim;
    }
    None
}

/// Per-value scales of a table, flattened.
pub fn scales(table: &[Field]) -> Vec<f32> {
    table.iter().flat_map(|f| f.scale.iter().copied()).collect()
}

/// Per-value noise amplitudes (after scaling) of a table, flattened.
pub fn noise_amplitudes(table: &[Field], level: f32) -> Vec<f32> {
    table
        .iter()
        .flat_map(|f| f.scale.iter().map(move |s| s * f.noise * level))
        .collect()
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn sizes_match_the_spec() {
        assert_eq!(OBS_DIM, 53);
        assert_eq!(LABEL_DIM, 14);
        assert_eq!(PRIVILEGED_DIM, 10);
        for f in OBSERVATION.iter().chain(&LABELS).chain(&PRIVILEGED) {
            assert_eq!(f.scale.len(), f.dim, "{}", f.name);
        }
        assert_eq!(slice_of(&OBSERVATION, "mode"), Some((45, 2)));
        assert_eq!(slice_of(&OBSERVATION, "clock"), Some((47, 4)));
    }
}
