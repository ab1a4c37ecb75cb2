//! Mass properties from an inertia tensor, with an eigen decomposition that stays exact when
//! principal moments coincide.
//!
//! parry's `MassProperties::with_inertia_matrix` takes the rotation of glam's f32 symmetric
//! eigen decomposition, which loses an axis when two moments are equal: the Go2's left hips,
//! whose y and z moments both sit on the inertia floor, came out without the armature about
//! their joint axis (0.002 kg m^2 about x instead of 0.022). A cyclic Jacobi sweep in f64
//! returns orthonormal axes whatever the multiplicities.

use rapier3d::math::{Mat3, Rotation, Vec3};
use rapier3d::prelude::MassProperties;

/// Eigenvalues and orthonormal, right-handed eigenvectors (columns) of a symmetric 3x3 matrix.
pub fn symmetric_eigen(m: Mat3) -> (Vec3, Mat3) {
    let mut a = [[0.0f64; 3]; 3];
    for (i, row) in a.iter_mut().enumerate() {
        for (j, v) in row.iter_mut().enumerate() {
            *v = 0.5 * f64::from(m.col(j)[i] + m.col(i)[j]);
        }
    }
    let mut v = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0f64]];
    for _sweep in 0..32 {
        let off = a[0][1].abs() + a[0][2].abs() + a[1][2].abs();
        if off < 1e-18 {
            break;
        }
        for (p, q) in [(0, 1), (0, 2), (1, 2)] {
            if a[p][q].abs() < 1e-300 {
                continue;
            }
            let theta = (a[q][q] - a[p][p]) / (2.0 * a[p][q]);
            let t = theta.signum() / (theta.abs() + (theta * theta + 1.0).sqrt());
            let t = if theta == 0.0 { 1.0 } else { t };
            let c = 1.0 / (t * t + 1.0).sqrt();
            let s = t * c;
            for row in a.iter_mut() {
                let (akp, akq) = (row[p], row[q]);
                row[p] = c * akp - s * akq;
                row[q] = s * akp + c * akq;
            }
            let (row_p, row_q) = (a[p], a[q]);
            for k in 0..3 {
                a[p][k] = c * row_p[k] - s * row_q[k];
                a[q][k] = s * row_p[k] + c * row_q[k];
            }
            for row in v.iter_mut() {
                let (vp, vq) = (row[p], row[q]);
                row[p] = c * vp - s * vq;
                row[q] = s * vp + c * vq;
            }
        }
    }
    let col = |j: usize| Vec3::new(v[0][j] as f32, v[1][j] as f32, v[2][j] as f32);
    let (x, y) = (col(0), col(1));
    // Right-handed: the third axis from the first two.
    let z = x.cross(y);
    (
        Vec3::new(a[0][0] as f32, a[1][1] as f32, a[2][2] as f32),
        Mat3::from_cols(x, y, z),
    )
}

/// Mass properties with centre of mass `com`, mass `mass` and inertia tensor `inertia` (about
/// the centre of mass, in the body frame).
pub fn mass_properties(com: Vec3, mass: f32, inertia: Mat3) -> MassProperties {
    let (moments, axes) = symmetric_eigen(inertia);
    let frame = Rotation::from_mat3(&axes).normalize();
    MassProperties::with_principal_inertia_frame(com, mass, moments.max(Vec3::ZERO), frame)
}

#[cfg(test)]
mod test {
    use super::*;

    fn reconstruct(moments: Vec3, axes: Mat3) -> Mat3 {
        axes * Mat3::from_diagonal(moments) * axes.transpose()
    }

    #[test]
    fn degenerate_moments_keep_every_axis() {
        // The FL hip of the Go2 on the 0.002 floor, plus armature 0.02 about x.
        let mut m = Mat3::from_cols(
            Vec3::new(0.002, -3.01e-6, 1.11e-6),
            Vec3::new(-3.01e-6, 0.002, -1.42e-6),
            Vec3::new(1.11e-6, -1.42e-6, 0.002),
        );
        m += Mat3::from_cols(Vec3::X * 0.02, Vec3::ZERO, Vec3::ZERO);
        let (moments, axes) = symmetric_eigen(m);
        assert!((axes.determinant() - 1.0).abs() < 1e-5);
        let back = reconstruct(moments, axes);
        for i in 0..3 {
            assert!(
                (back.col(i) - m.col(i)).abs().max_element() < 1e-7,
                "{back:?} vs {m:?}"
            );
        }
        let mp = mass_properties(Vec3::ZERO, 1.0, m);
        let about_x = Vec3::X.dot(mp.reconstruct_inertia_matrix() * Vec3::X);
        assert!((about_x - 0.022).abs() < 1e-6, "{about_x}");
    }

    #[test]
    fn a_rotated_tensor_is_recovered() {
        let r = Mat3::from_quat(Rotation::from_euler(
            rapier3d::math::glamx::EulerRot::XYZ,
            0.3,
            -0.7,
            1.1,
        ));
        let m = r * Mat3::from_diagonal(Vec3::new(0.1, 0.2, 0.05)) * r.transpose();
        let (moments, axes) = symmetric_eigen(m);
        let back = reconstruct(moments, axes);
        for i in 0..3 {
            assert!((back.col(i) - m.col(i)).abs().max_element() < 1e-6);
        }
    }
}
