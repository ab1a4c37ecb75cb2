//! Spatial (6D) vector algebra on plain arrays, after Featherstone ch. 2.
//!
//! Everything is expressed in world-aligned axes about one reference point (the base origin, see
//! [`super::Workspace`]), so no 6x6 transforms are needed between bodies: a body's motion
//! subspace, velocity, inertia and force are all in the same frame, as in MuJoCo's `cdof`/`cinert`.
//!
//! - motion vector `[w; v]`: angular velocity, then the velocity of the body point at the
//!   reference point;
//! - force vector `[n; f]`: moment about the reference point, then force;
//! - spatial inertia, 10 numbers `[m, h (3), I (6)]`: mass, first moment `h = m c` (c the centre
//!   of mass relative to the reference point) and the rotational inertia about the reference
//!   point as `[xx, yy, zz, xy, xz, yz]`.

use super::scalar::Real;

/// A 3-vector.
pub type Vec3<T> = [T; 3];
/// A 3x3 matrix, row-major.
pub type Mat3<T> = [T; 9];
/// A spatial motion or force vector (angular part first).
pub type Vec6<T> = [T; 6];
/// A spatial inertia `[m, hx, hy, hz, Ixx, Iyy, Izz, Ixy, Ixz, Iyz]`.
pub type Inertia<T> = [T; 10];

/// Cross product.
#[inline]
pub fn cross<T: Real>(a: &Vec3<T>, b: &Vec3<T>) -> Vec3<T> {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Dot product.
#[inline]
pub fn dot<T: Real>(a: &Vec3<T>, b: &Vec3<T>) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a + b`.
#[inline]
pub fn add<T: Real>(a: &Vec3<T>, b: &Vec3<T>) -> Vec3<T> {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `s a`.
#[inline]
pub fn scale<T: Real>(s: T, a: &Vec3<T>) -> Vec3<T> {
    [s * a[0], s * a[1], s * a[2]]
}

/// `m v`.
#[inline]
pub fn mat_vec<T: Real>(m: &Mat3<T>, v: &Vec3<T>) -> Vec3<T> {
    [
        m[0] * v[0] + m[1] * v[1] + m[2] * v[2],
        m[3] * v[0] + m[4] * v[1] + m[5] * v[2],
        m[6] * v[0] + m[7] * v[1] + m[8] * v[2],
    ]
}

/// `a b`.
#[inline]
pub fn mat_mul<T: Real>(a: &Mat3<T>, b: &Mat3<T>) -> Mat3<T> {
    let mut out = [T::ZERO; 9];
    for r in 0..3 {
        for c in 0..3 {
            out[3 * r + c] = a[3 * r] * b[c] + a[3 * r + 1] * b[3 + c] + a[3 * r + 2] * b[6 + c];
        }
    }
    out
}

/// Column `c` of `m`.
#[inline]
pub fn column<T: Real>(m: &Mat3<T>, c: usize) -> Vec3<T> {
    [m[c], m[3 + c], m[6 + c]]
}

/// The identity matrix.
pub fn identity<T: Real>() -> Mat3<T> {
    let (o, z) = (T::ONE, T::ZERO);
    [o, z, z, z, o, z, z, z, o]
}

/// Rotation matrix of a quaternion `[w, x, y, z]`, normalised first (as MuJoCo does).
pub fn quat_to_mat<T: Real>(q: &[T; 4]) -> Mat3<T> {
    let norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    let inv = T::ONE / norm;
    let (w, x, y, z) = (q[0] * inv, q[1] * inv, q[2] * inv, q[3] * inv);
    let two = T::from_f64(2.0);
    [
        T::ONE - two * (y * y + z * z),
        two * (x * y - w * z),
        two * (x * z + w * y),
        two * (x * y + w * z),
        T::ONE - two * (x * x + z * z),
        two * (y * z - w * x),
        two * (x * z - w * y),
        two * (y * z + w * x),
        T::ONE - two * (x * x + y * y),
    ]
}

/// Rotation by `angle` about the unit `axis` (Rodrigues).
pub fn axis_angle<T: Real>(axis: &Vec3<T>, angle: T) -> Mat3<T> {
    let (s, c) = angle.sin_cos();
    let t = T::ONE - c;
    let [x, y, z] = *axis;
    [
        c + t * x * x,
        t * x * y - s * z,
        t * x * z + s * y,
        t * x * y + s * z,
        c + t * y * y,
        t * y * z - s * x,
        t * x * z - s * y,
        t * y * z + s * x,
        c + t * z * z,
    ]
}

/// Dot product of a motion and a force vector (power).
#[inline]
pub fn dot6<T: Real>(a: &Vec6<T>, b: &Vec6<T>) -> T {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + a[3] * b[3] + a[4] * b[4] + a[5] * b[5]
}

/// `a + s b`, in place.
#[inline]
pub fn add_scaled6<T: Real>(a: &mut Vec6<T>, s: T, b: &Vec6<T>) {
    for (x, y) in a.iter_mut().zip(b) {
        *x += s * *y;
    }
}

/// Motion cross motion, `v x m` (the rate of change of `m` carried by velocity `v`).
#[inline]
pub fn cross_motion<T: Real>(v: &Vec6<T>, m: &Vec6<T>) -> Vec6<T> {
    let (w, vl) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
    let (mw, ml) = ([m[0], m[1], m[2]], [m[3], m[4], m[5]]);
    let a = cross(&w, &mw);
    let b = add(&cross(&w, &ml), &cross(&vl, &mw));
    [a[0], a[1], a[2], b[0], b[1], b[2]]
}

/// Motion cross force, `v x* f`.
#[inline]
pub fn cross_force<T: Real>(v: &Vec6<T>, f: &Vec6<T>) -> Vec6<T> {
    let (w, vl) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
    let (n, fl) = ([f[0], f[1], f[2]], [f[3], f[4], f[5]]);
    let a = add(&cross(&w, &n), &cross(&vl, &fl));
    let b = cross(&w, &fl);
    [a[0], a[1], a[2], b[0], b[1], b[2]]
}

/// Spatial inertia times motion: the momentum (or force) `I v`.
#[inline]
pub fn inertia_mul<T: Real>(i: &Inertia<T>, v: &Vec6<T>) -> Vec6<T> {
    let m = i[0];
    let h = [i[1], i[2], i[3]];
    let (w, vl) = ([v[0], v[1], v[2]], [v[3], v[4], v[5]]);
    let iw = [
        i[4] * w[0] + i[7] * w[1] + i[8] * w[2],
        i[7] * w[0] + i[5] * w[1] + i[9] * w[2],
        i[8] * w[0] + i[9] * w[1] + i[6] * w[2],
    ];
    let hv = cross(&h, &vl);
    let hw = cross(&h, &w);
    [
        iw[0] + hv[0],
        iw[1] + hv[1],
        iw[2] + hv[2],
        m * vl[0] - hw[0],
        m * vl[1] - hw[1],
        m * vl[2] - hw[2],
    ]
}

/// `a += b` for spatial inertias about the same point (a composite body).
#[inline]
pub fn inertia_add<T: Real>(a: &mut Inertia<T>, b: &Inertia<T>) {
    for (x, y) in a.iter_mut().zip(b) {
        *x += *y;
    }
}

/// Spatial inertia about the reference point of a body with `mass`, centre of mass `com`
/// (relative to the reference point, world axes) and rotational inertia `ic` about its centre of
/// mass in world axes (`[xx, yy, zz, xy, xz, yz]`): the parallel-axis theorem.
pub fn inertia_at<T: Real>(mass: T, com: &Vec3<T>, ic: &[T; 6]) -> Inertia<T> {
    let [cx, cy, cz] = *com;
    [
        mass,
        mass * cx,
        mass * cy,
        mass * cz,
        ic[0] + mass * (cy * cy + cz * cz),
        ic[1] + mass * (cx * cx + cz * cz),
        ic[2] + mass * (cx * cx + cy * cy),
        ic[3] - mass * cx * cy,
        ic[4] - mass * cx * cz,
        ic[5] - mass * cy * cz,
    ]
}

/// `r s r^T` for a symmetric `s` given as `[xx, yy, zz, xy, xz, yz]`, in the same layout.
pub fn rotate_symmetric<T: Real>(r: &Mat3<T>, s: &[T; 6]) -> [T; 6] {
    let full = [s[0], s[3], s[4], s[3], s[1], s[5], s[4], s[5], s[2]];
    let rs = mat_mul(r, &full);
    // (r s) r^T: entry (a, b) = row a of rs dot row b of r.
    let e = |a: usize, b: usize| {
        rs[3 * a] * r[3 * b] + rs[3 * a + 1] * r[3 * b + 1] + rs[3 * a + 2] * r[3 * b + 2]
    };
    [e(0, 0), e(1, 1), e(2, 2), e(0, 1), e(0, 2), e(1, 2)]
}
