//! The robot's left-right mirror on the actor's inputs and outputs, and the mirror loss
//! (client-py's `unigait.algorithms.symmetry`; decision record 0033).
//!
//! The Go2 and the task are symmetric about the base's x-z plane; PPO does not see it, and a
//! long run drifts into lopsided gaits. The mirror loss `mean (mu(M x) - M mu(x))^2`, with the
//! target detached, pulls the actor towards the symmetric policy. Each map is a signed
//! permutation built from the session spec by field name: a field it does not know is refused.

use burn::prelude::*;
use unigait_client::Spec;

use crate::nets::matrix;
use crate::{Error, Result};

/// Leg swap of the mirror: FL <-> FR, RL <-> RR (joints, clocks, contacts, feet).
pub const FOOT_SWAP: [usize; 4] = [1, 0, 3, 2];

/// `y[i] = sign[i] * x[index[i]]`: the mirror of a flat vector.
#[derive(Debug, Clone, PartialEq)]
pub struct SignedPermutation {
    /// Source of each value.
    pub index: Vec<usize>,
    /// Its sign.
    pub sign: Vec<f32>,
}

impl SignedPermutation {
    fn identity(n: usize) -> Self {
        Self {
            index: (0..n).collect(),
            sign: vec![1.0; n],
        }
    }

    /// The mirror of one row.
    pub fn apply(&self, x: &[f32]) -> Vec<f32> {
        self.index
            .iter()
            .zip(&self.sign)
            .map(|(&i, &s)| s * x[i])
            .collect()
    }

    /// The mirror of the concatenation of the vectors `parts` mirror, in order.
    pub fn concat(parts: &[&SignedPermutation]) -> Self {
        let mut out = Self {
            index: Vec::new(),
            sign: Vec::new(),
        };
        for p in parts {
            let offset = out.index.len();
            out.index.extend(p.index.iter().map(|i| i + offset));
            out.sign.extend_from_slice(&p.sign);
        }
        out
    }

    /// f32 [n, n] with `x.matmul(m)` the mirror of each row of `x`.
    pub fn matrix(&self, device: &Device) -> Tensor<2> {
        let n = self.index.len();
        let mut m = vec![0.0; n * n];
        for (i, (&j, &s)) in self.index.iter().zip(&self.sign).enumerate() {
            m[j * n + i] = s;
        }
        matrix(m, n, n, device)
    }
}

/// The 12 joints' mirror from their names: `FL_*` <-> `FR_*`, `RL_*` <-> `RR_*`, hips negated.
/// The defaults are mirror-symmetric, so it holds for offsets from them, speeds and actions.
pub fn joint_mirror(names: &[String]) -> Result<SignedPermutation> {
    let unknown = |n: &str| Error::Spec(format!("no mirror for joint {n:?}"));
    let mut out = SignedPermutation::identity(0);
    for name in names {
        let (leg, rest) = name.split_once('_').ok_or_else(|| unknown(name))?;
        let other = match leg {
            "FL" => "FR",
            "FR" => "FL",
            "RL" => "RR",
            "RR" => "RL",
            _ => return Err(unknown(name)),
        };
        let twin = format!("{other}_{rest}");
        let j = names
            .iter()
            .position(|n| *n == twin)
            .ok_or_else(|| unknown(name))?;
        out.index.push(j);
        out.sign.push(if rest.contains("hip") { -1.0 } else { 1.0 });
    }
    Ok(out)
}

/// The mirror of one named field of o_t or e_t.
fn field_mirror(name: &str, size: usize, joints: &SignedPermutation) -> Result<SignedPermutation> {
    // Vectors flip y; the angular velocity (a pseudovector) flips x and z; the command is
    // (vx, vy, wz), the orientation (gravity y, pitch, gravity z).
    let vector = match name {
        "cmd" => Some([1.0, -1.0, -1.0]),
        "phi" => Some([-1.0, 1.0, 1.0]),
        "omega" => Some([-1.0, 1.0, -1.0]),
        "base_lin_vel" | "terrain_normal" => Some([1.0, -1.0, 1.0]),
        _ => None,
    };
    match (name, vector) {
        (_, Some(sign)) if size == 3 => Ok(SignedPermutation {
            index: vec![0, 1, 2],
            sign: sign.to_vec(),
        }),
        ("q" | "qdot" | "last_action", _) if size == joints.index.len() => Ok(joints.clone()),
        ("clock" | "foot_contact" | "foot_height", _) if size == FOOT_SWAP.len() => {
            Ok(SignedPermutation {
                index: FOOT_SWAP.to_vec(),
                sign: vec![1.0; 4],
            })
        }
        ("mode" | "ratio", _) => Ok(SignedPermutation::identity(size)),
        _ => Err(Error::Spec(format!(
            "no mirror for field {name:?} of size {size}"
        ))),
    }
}

/// The mirror of one spec tensor's row (`obs` or `labels`), field by field.
pub fn tensor_mirror(spec: &Spec, tensor: &str) -> Result<SignedPermutation> {
    let joints = joint_mirror(&spec.0.joint_names)?;
    let t = spec
        .tensor(tensor)
        .ok_or_else(|| Error::Spec(format!("the spec has no `{tensor}` tensor")))?;
    let parts = t
        .fields
        .iter()
        .map(|f| field_mirror(&f.name, f.size as usize, &joints))
        .collect::<Result<Vec<_>>>()?;
    let out = SignedPermutation::concat(&parts.iter().collect::<Vec<_>>());
    let size = spec.row_size(tensor).unwrap_or(0);
    if out.index.len() != size {
        return Err(Error::Spec(format!(
            "{tensor}'s fields cover {} of its {size} values",
            out.index.len()
        )));
    }
    Ok(out)
}

/// The mirror of the actor's input (o_t history, then the estimate) and of its actions.
#[derive(Debug, Clone, PartialEq)]
pub struct ActorMirror {
    /// Of the actor's input.
    pub actor_obs: SignedPermutation,
    /// Of the actions.
    pub actions: SignedPermutation,
}

impl ActorMirror {
    /// From a session's spec and the history length.
    pub fn from_spec(spec: &Spec, history_length: usize) -> Result<Self> {
        let obs = tensor_mirror(spec, "obs")?;
        let labels = tensor_mirror(spec, "labels")?;
        let mut parts = vec![&obs; history_length];
        parts.push(&labels);
        Ok(Self {
            actor_obs: SignedPermutation::concat(&parts),
            actions: joint_mirror(&spec.0.joint_names)?,
        })
    }
}

/// `mean((mu(M x) - M mu(x))^2)` over batch and actions, the target `M mu(x)` detached:
/// `mean` is mu(x) [B, A], `mirrored_mean` mu(M x), `actions` the mirror's matrix [A, A].
pub fn mirror_loss(mean: Tensor<2>, mirrored_mean: Tensor<2>, actions: Tensor<2>) -> Tensor<1> {
    let target = mean.detach().matmul(actions);
    (mirrored_mean - target).square().mean()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::nets::{device, values};
    use unigait_proto::v1;

    fn spec() -> Spec {
        let tensor = |name: &str, fields: &[(&str, u32)]| {
            let mut offset = 0;
            let mut t = v1::TensorSpec {
                name: name.into(),
                ..Default::default()
            };
            for &(f, size) in fields {
                t.fields.push(v1::FieldSpec {
                    name: f.into(),
                    offset,
                    size,
                    doc: String::new(),
                });
                offset += size;
            }
            t.shape.push(offset);
            t
        };
        let obs: &[(&str, u32)] = &[
            ("cmd", 3),
            ("phi", 3),
            ("omega", 3),
            ("q", 12),
            ("qdot", 12),
            ("last_action", 12),
            ("mode", 2),
            ("clock", 4),
            ("ratio", 2),
        ];
        let labels: &[(&str, u32)] = &[
            ("base_lin_vel", 3),
            ("foot_contact", 4),
            ("terrain_normal", 3),
            ("foot_height", 4),
        ];
        Spec(v1::Spec {
            joint_names: ["FL", "FR", "RL", "RR"]
                .iter()
                .flat_map(|l| ["hip", "thigh", "calf"].map(|j| format!("{l}_{j}_joint")))
                .collect(),
            tensors: vec![tensor("obs", obs), tensor("labels", labels)],
            ..Default::default()
        })
    }

    #[test]
    fn the_maps_match_the_python_learners_on_known_values() {
        let s = spec();
        let j = joint_mirror(&s.0.joint_names).unwrap();
        let q = [
            0.3, 0.9, -1.4, -0.2, 0.7, -1.6, 0.05, 1.1, -1.3, 0.0, 1.2, -1.7,
        ];
        let expected = [
            0.2, 0.7, -1.6, -0.3, 0.9, -1.4, 0.0, 1.2, -1.7, -0.05, 1.1, -1.3,
        ];
        assert_eq!(j.apply(&q), expected);
        let mut o = vec![0.0; 53];
        o[..9].copy_from_slice(&[1.0, 0.4, 0.1, 0.2, 1.3, -0.5, 0.3, -0.6, 0.9]);
        o[47..51].copy_from_slice(&[0.5, -0.5, 0.0, 0.0]);
        let r = tensor_mirror(&s, "obs").unwrap().apply(&o);
        let head = [1.0, -0.4, -0.1, -0.2, 1.3, -0.5, -0.3, -0.6, -0.9];
        assert_eq!(&r[..9], &head);
        assert_eq!(&r[47..51], &[-0.5, 0.5, 0.0, 0.0]);
        let e = [
            0.5, 0.2, -0.1, 1., 0., 0., 1., 0.1, 0.3, 0.9, 0.02, 0.08, 0.0, 0.05,
        ];
        let r = tensor_mirror(&s, "labels").unwrap().apply(&e);
        let expected = [
            0.5, -0.2, -0.1, 0., 1., 1., 0., 0.1, -0.3, 0.9, 0.08, 0.02, 0.05, 0.0,
        ];
        assert_eq!(r, expected);
    }

    #[test]
    fn mirroring_twice_gives_back_the_input_and_the_matrix_is_the_map() {
        let m = ActorMirror::from_spec(&spec(), 3).unwrap();
        assert_eq!(m.actor_obs.index.len(), 3 * 53 + 14);
        let x: Vec<f32> = (0..173).map(|i| (i as f32 * 0.37).sin()).collect();
        assert_eq!(m.actor_obs.apply(&m.actor_obs.apply(&x)), x);
        let d = device();
        let by_matrix = matrix(x.clone(), 1, 173, &d).matmul(m.actor_obs.matrix(&d));
        let got = values(by_matrix).unwrap();
        assert_eq!(got, m.actor_obs.apply(&x));
    }

    #[test]
    fn a_field_without_a_mirror_is_refused() {
        let mut s = spec();
        let obs = &mut s.0.tensors[0];
        obs.fields.push(v1::FieldSpec {
            name: "height_scan".into(),
            offset: 53,
            size: 5,
            doc: String::new(),
        });
        obs.shape[0] = 58;
        let e = ActorMirror::from_spec(&s, 3).unwrap_err().to_string();
        assert!(e.contains("height_scan"), "{e}");
    }

    #[test]
    fn the_mirror_loss_on_known_numbers() {
        let d = device();
        let m = ActorMirror::from_spec(&spec(), 3).unwrap();
        let mut mean = vec![0.0; 12];
        mean[0] = 0.5; // FL hip: its mirror is -0.5 on the FR hip
        let mean = matrix(mean, 1, 12, &d);
        let mirrored = matrix(vec![0.0; 12], 1, 12, &d).require_grad();
        let loss = mirror_loss(mean, mirrored.clone(), m.actions.matrix(&d));
        let v = values(loss.clone()).unwrap()[0];
        assert!((v - 0.25 / 12.0).abs() < 1e-7, "{v}");
        let grads = loss.backward();
        let g = values(mirrored.grad(&grads).unwrap()).unwrap();
        assert!((g[3] - 2.0 * 0.5 / 12.0).abs() < 1e-7, "{g:?}");
    }
}
