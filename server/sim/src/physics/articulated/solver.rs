//! Constraints in joint space: contact and joint-limit rows, MuJoCo-style soft constraints, and a
//! projected Gauss-Seidel solve on the rows.
//!
//! A row `i` has a Jacobian `J_i` (1 x nv) mapping generalised velocity to the constraint's
//! velocity and a bound on its impulse `lambda_i` (normal and limit rows: `lambda >= 0`;
//! friction rows: `|lambda| <= mu lambda_normal`, a box cone). The rows couple through the
//! Delassus matrix `A = J M^-1 J^T`, built from the mass matrix's factor `M = L^T D L` as
//! `A = Y^T D^-1 Y` with `Y = L^-T J^T` (each `Y_i` keeps `J_i`'s sparsity: the contact body's
//! ancestor DoFs). Gauss-Seidel then works on the rows' velocities `u = J v` alone (`n` numbers
//! per row update instead of `2 nv`), and the velocity change is one solve,
//! `M^-1 J^T lambda`, at the end.
//!
//! Soft rows (a penetrating contact, a joint past its stop) follow MuJoCo's constraint model
//! (documentation, "Computation"): with impedance `d` (solimp) the row is regularised by
//! `R = (1 - d) / d A_ii` and aims at the reference acceleration `a_ref = -b (J v) - k d r`
//! (`r` the signed distance, `b = 2 / (d_max tau)`, `k = 1 / (d_max^2 tau^2 zeta^2)` from solref).
//! At the velocity level of a step `h`, MuJoCo's optimality condition
//! `J qacc = a_ref - R f` becomes `J v+ + R lambda = J v + h a_ref` (`lambda = h f`): no
//! position correction is needed and `A + R` stays well conditioned.
//!
//! Rows that are still apart (a contact within the prediction distance, a joint short of its
//! stop) are speculative and hard: `J v+ >= -r / h` lets the row close the gap within this step
//! but not cross it, so a fast foot or joint cannot pass through in one step and then be pushed
//! back (the stop overshoot the rapier engine shows).

/// MuJoCo's `solref` and `solimp` for the soft rows: MuJoCo's defaults but for the time
/// constant, 0.01 s instead of 0.02 (twice our 5 ms step, the stiffest MuJoCo allows): with 0.02 a
/// calf whipped into its stop at 30 rad/s went 0.14 rad past it (the soft row removes only
/// `h b` = 53% of the closing speed per step), with 0.01 about 0.02 rad.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SoftConstraint {
    /// Time constant (s), solref[0]. Must be at least twice the step.
    pub timeconst: f64,
    /// Damping ratio, solref[1].
    pub dampratio: f64,
    /// Impedance at zero penetration, solimp[0].
    pub d0: f64,
    /// Impedance at `width` penetration and beyond, solimp[1].
    pub dwidth: f64,
    /// Penetration (m or rad) over which the impedance goes from `d0` to `dwidth`, solimp[2].
    pub width: f64,
    /// Midpoint of the impedance sigmoid, solimp[3].
    pub midpoint: f64,
    /// Power of the impedance sigmoid, solimp[4].
    pub power: f64,
    /// Ratio of a friction row's impedance to its normal row's, MuJoCo's `impratio`: the
    /// friction rows' regulariser is the normal one's divided by it. MuJoCo's default is 1;
    /// the Menagerie Go2 (and Playground) use 100: with 1 a loaded foot creeps at several cm/s
    /// (steady slip `v = R f / b`), and the robot sinks as its feet splay (measured here: base
    /// 0.218 m instead of 0.27 after a drop, still sliding at 3 cm/s).
    pub impratio: f64,
}

impl Default for SoftConstraint {
    fn default() -> Self {
        Self {
            timeconst: 0.01,
            dampratio: 1.0,
            d0: 0.9,
            dwidth: 0.95,
            width: 0.001,
            midpoint: 0.5,
            power: 2.0,
            impratio: 100.0,
        }
    }
}

impl SoftConstraint {
    /// Impedance at penetration `depth` (>= 0), MuJoCo's `getimpedance`.
    pub fn impedance(&self, depth: f64) -> f64 {
        let x = if self.width > 0.0 {
            (depth / self.width).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let (mid, p) = (self.midpoint, self.power);
        // powf costs tens of ns, several times per contact and step: the default power 2 is a
        // product.
        let pow = |b: f64, e: f64| {
            if e == 2.0 {
                b * b
            } else if e == 1.0 {
                b
            } else {
                b.powf(e)
            }
        };
        let y = if x <= mid {
            pow(x, p) / pow(mid, p - 1.0)
        } else {
            1.0 - pow(1.0 - x, p) / pow(1.0 - mid, p - 1.0)
        };
        (self.d0 + y * (self.dwidth - self.d0)).clamp(1e-4, 0.9999)
    }

    /// Damping `b` (1/s) and stiffness `k` (1/s^2) of the reference acceleration.
    pub fn reference_gains(&self) -> (f64, f64) {
        let dmax = self.dwidth.clamp(1e-4, 0.9999);
        let b = 2.0 / (dmax * self.timeconst);
        let k = 1.0 / (dmax * dmax * self.timeconst * self.timeconst * self.dampratio.powi(2));
        (b, k)
    }
}

/// What bounds a row's impulse.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RowKind {
    /// `lambda >= 0` (contact normal, joint limit).
    Unilateral,
    /// `|lambda| <= mu lambda[normal]`: a friction direction of the contact whose normal row is
    /// `normal`.
    Friction {
        /// Index of the normal row.
        normal: usize,
        /// Friction coefficient.
        mu: f64,
    },
}

/// The rows of one robot's step, in preallocated storage (capacity fixed at creation).
#[derive(Clone, Debug)]
pub struct Rows {
    nv: usize,
    capacity: usize,
    len: usize,
    /// Row Jacobians, `len x nv`, row-major.
    pub(super) jacobian: Vec<f64>,
    /// `Y_i = L^-T J_i^T` per row, same layout (the caller fills it).
    pub(super) half: Vec<f64>,
    /// The Delassus matrix `A = J M^-1 J^T`, row-major with stride `capacity`.
    pub(super) delassus: Vec<f64>,
    /// Regulariser `R_i`.
    pub(super) regulariser: Vec<f64>,
    /// `1 / (A_ii + R_i)`.
    pub(super) inverse_denominator: Vec<f64>,
    /// The right-hand side `J v + h a_ref` (soft) or `-r / h` (speculative).
    pub(super) target: Vec<f64>,
    /// Solved impulses.
    pub(super) impulse: Vec<f64>,
    /// Row velocities `u = J v` during the solve.
    pub(super) velocity: Vec<f64>,
    pub(super) kind: Vec<RowKind>,
    /// Caller's tag per row (which collider or joint it belongs to).
    pub(super) tag: Vec<u32>,
    /// Per row: the deepest DoF its Jacobian may touch (the contact body's own DoF); the row's
    /// nonzeros lie on that DoF's ancestor chain.
    pub(super) dof: Vec<usize>,
}

impl Rows {
    /// Storage for up to `capacity` rows of `nv` DoFs.
    pub fn new(nv: usize, capacity: usize) -> Self {
        Self {
            nv,
            capacity,
            len: 0,
            jacobian: vec![0.0; capacity * nv],
            half: vec![0.0; capacity * nv],
            delassus: vec![0.0; capacity * capacity],
            regulariser: vec![0.0; capacity],
            inverse_denominator: vec![0.0; capacity],
            target: vec![0.0; capacity],
            impulse: vec![0.0; capacity],
            velocity: vec![0.0; capacity],
            kind: vec![RowKind::Unilateral; capacity],
            tag: vec![0; capacity],
            dof: vec![0; capacity],
        }
    }

    /// Number of rows in use.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether no row is in use.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Free rows left.
    pub fn room(&self) -> usize {
        self.capacity - self.len
    }

    /// Forget every row.
    pub fn clear(&mut self) {
        self.len = 0;
    }

    /// Append a row with a zeroed Jacobian, nonzero at most on the ancestor chain of DoF `dof`;
    /// returns its index and the Jacobian to fill. The caller checks [`Rows::room`] first.
    pub fn push(&mut self, kind: RowKind, tag: u32, dof: usize) -> (usize, &mut [f64]) {
        let i = self.len;
        assert!(i < self.capacity, "constraint rows full");
        self.len += 1;
        self.kind[i] = kind;
        self.tag[i] = tag;
        self.dof[i] = dof;
        self.impulse[i] = 0.0;
        let j = &mut self.jacobian[i * self.nv..(i + 1) * self.nv];
        j.fill(0.0);
        (i, j)
    }

    /// Row `i`'s Jacobian.
    pub fn jacobian(&self, i: usize) -> &[f64] {
        &self.jacobian[i * self.nv..(i + 1) * self.nv]
    }

    /// Solved impulse of row `i` (N s or N m s).
    pub fn impulse(&self, i: usize) -> f64 {
        self.impulse[i]
    }

    /// Caller's tag of row `i`.
    pub fn tag(&self, i: usize) -> u32 {
        self.tag[i]
    }

    /// The Delassus matrix from the rows' `Y_i` (in `half`) and the inverse of the factor's
    /// pivots `D`: `A_ij = sum_k Y_ik Y_jk / D_k`. `chain(k)` lists DoF `k`'s ancestors and
    /// itself, root first: two rows share only the common prefix of their chains (the base's
    /// six DoFs for contacts on different legs), and the sum runs over it alone.
    pub(super) fn assemble<'a>(
        &mut self,
        inverse_pivots: &[f64],
        chain: impl Fn(usize) -> &'a [usize],
    ) {
        let (nv, cap) = (self.nv, self.capacity);
        for i in 0..self.len {
            let yi = &self.half[i * nv..(i + 1) * nv];
            let ci = chain(self.dof[i]);
            for j in 0..=i {
                let yj = &self.half[j * nv..(j + 1) * nv];
                let cj = chain(self.dof[j]);
                let a: f64 = ci
                    .iter()
                    .zip(cj)
                    .take_while(|(x, y)| x == y)
                    .map(|(&k, _)| yi[k] * yj[k] * inverse_pivots[k])
                    .sum();
                self.delassus[i * cap + j] = a;
                self.delassus[j * cap + i] = a;
            }
        }
    }

    /// Row `i`'s regulariser and target (after [`Rows::assemble`]): soft with impedance `d` and
    /// reference `target` when `soft` (the regulariser divided by `soft_ratio`), else hard.
    pub(super) fn finish(&mut self, i: usize, soft: Option<f64>, soft_ratio: f64, target: f64) {
        let a = self.delassus[i * self.capacity + i].max(1e-12);
        // A hard row keeps a tiny regulariser so that redundant rows (a box's four corners on
        // the ground) leave the iteration well defined.
        let r = match soft {
            Some(d) => (1.0 - d) / d * a / soft_ratio,
            None => 1e-6 * a,
        };
        self.regulariser[i] = r;
        self.inverse_denominator[i] = 1.0 / (a + r);
        self.target[i] = target;
    }

    /// Start from the impulses already in the rows (the last step's, 0 for new rows), projected
    /// on their bounds, at the unconstrained velocity `v_free`: `u = J v_free + A lambda`.
    pub fn warm_start(&mut self, v_free: &[f64]) {
        let (nv, cap) = (self.nv, self.capacity);
        for i in 0..self.len {
            self.impulse[i] = match self.kind[i] {
                RowKind::Unilateral => self.impulse[i].max(0.0),
                RowKind::Friction { normal, mu } => {
                    let bound = mu * self.impulse[normal];
                    self.impulse[i].clamp(-bound, bound)
                }
            };
        }
        for i in 0..self.len {
            let coupled: f64 = self.delassus[i * cap..i * cap + self.len]
                .iter()
                .zip(&self.impulse[..self.len])
                .map(|(a, l)| a * l)
                .sum();
            self.velocity[i] = dot(&self.jacobian[i * nv..(i + 1) * nv], v_free) + coupled;
        }
    }

    /// Projected Gauss-Seidel on the row velocities from [`Rows::warm_start`]. Stops after
    /// `max_sweeps` sweeps or when no impulse moved by more than `tolerance` (N s) in a sweep;
    /// returns the sweeps done.
    pub fn solve(&mut self, max_sweeps: usize, tolerance: f64) -> usize {
        let (n, cap) = (self.len, self.capacity);
        for sweep in 1..=max_sweeps {
            let mut largest: f64 = 0.0;
            for i in 0..n {
                let residual =
                    self.velocity[i] + self.regulariser[i] * self.impulse[i] - self.target[i];
                let old = self.impulse[i];
                let free = old - residual * self.inverse_denominator[i];
                let new = match self.kind[i] {
                    RowKind::Unilateral => free.max(0.0),
                    RowKind::Friction { normal, mu } => {
                        let bound = mu * self.impulse[normal];
                        free.clamp(-bound, bound)
                    }
                };
                let delta = new - old;
                if delta != 0.0 {
                    self.impulse[i] = new;
                    // A is symmetric: column i is row i.
                    let column = &self.delassus[i * cap..i * cap + n];
                    for (u, &a) in self.velocity[..n].iter_mut().zip(column) {
                        *u += delta * a;
                    }
                    largest = largest.max(delta.abs());
                }
            }
            if largest <= tolerance {
                return sweep;
            }
        }
        max_sweeps
    }

    /// `out = J^T lambda`, the generalised impulse of the solved rows.
    pub fn generalised_impulse(&self, out: &mut [f64]) {
        let nv = self.nv;
        out.fill(0.0);
        for i in 0..self.len {
            let l = self.impulse[i];
            if l != 0.0 {
                for (o, &j) in out.iter_mut().zip(&self.jacobian[i * nv..(i + 1) * nv]) {
                    *o += l * j;
                }
            }
        }
    }
}

#[inline]
fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

#[cfg(test)]
mod test {
    use super::*;

    #[test]
    fn impedance_follows_mujocos_sigmoid() {
        let s = SoftConstraint::default();
        assert!((s.impedance(0.0) - 0.9).abs() < 1e-12);
        assert!((s.impedance(0.002) - 0.95).abs() < 1e-12);
        // Midpoint: y = 0.5, d = 0.925; a quarter: y = 0.25^2 / 0.5 = 0.125.
        assert!((s.impedance(0.0005) - 0.925).abs() < 1e-12);
        assert!((s.impedance(0.00025) - (0.9 + 0.125 * 0.05)).abs() < 1e-12);
        let (b, k) = s.reference_gains();
        assert!((b - 2.0 / (0.95 * 0.01)).abs() < 1e-9);
        assert!((k - 1.0 / (0.95f64.powi(2) * 0.0001)).abs() < 1e-6);
    }

    /// Rows over a diagonal mass matrix `M = diag(masses)` with one-hot Jacobians.
    fn rows_on(masses: &[f64], rows: &[(RowKind, usize)]) -> Rows {
        let nv = masses.len();
        let mut r = Rows::new(nv, 8);
        for &(kind, dof) in rows {
            let (i, j) = r.push(kind, 0, dof);
            j[dof] = 1.0;
            // L = I, D = M: Y = J.
            r.half[i * nv + dof] = 1.0;
        }
        let inverse: Vec<f64> = masses.iter().map(|m| 1.0 / m).collect();
        // Every DoF its own root: rows on different DoFs do not couple.
        let chains: Vec<Vec<usize>> = (0..nv).map(|k| vec![k]).collect();
        r.assemble(&inverse, |k| &chains[k]);
        r
    }

    /// A unit mass on the ground (one DoF, vertical): a hard row stops its fall exactly, and a
    /// soft row at rest carries the weight with the regulariser's share.
    #[test]
    fn one_row_on_a_unit_mass() {
        let mut rows = rows_on(&[1.0], &[(RowKind::Unilateral, 0)]);
        rows.finish(0, None, 1.0, 0.0);
        rows.warm_start(&[-2.0]);
        rows.solve(10, 1e-12);
        assert!(rows.velocity[0].abs() < 1e-5, "{}", rows.velocity[0]);
        assert!((rows.impulse(0) - 2.0).abs() < 1e-5);
        let mut p = [0.0];
        rows.generalised_impulse(&mut p);
        assert!((p[0] - 2.0).abs() < 1e-5);

        // Soft: J v+ + R lambda = target; with A = 1, d = 0.9, R = 1/9, target 0 and v_free =
        // -0.05: lambda (1 + 1/9) = 0.05.
        let mut rows = rows_on(&[1.0], &[(RowKind::Unilateral, 0)]);
        rows.finish(0, Some(0.9), 1.0, 0.0);
        rows.warm_start(&[-0.05]);
        rows.solve(10, 1e-14);
        assert!(
            (rows.impulse(0) - 0.045).abs() < 1e-12,
            "{}",
            rows.impulse(0)
        );
    }

    /// Friction rows stay in the box cone `|lambda_t| <= mu lambda_n`; the Delassus matrix
    /// carries the mass (a 2 kg body sliding at 3 m/s, falling at 1 m/s: normal impulse 2 N s,
    /// friction at most 1 N s, which takes 0.5 m/s off the slide).
    #[test]
    fn friction_is_bounded_by_the_normal_impulse() {
        let friction = RowKind::Friction { normal: 0, mu: 0.5 };
        let mut rows = rows_on(&[2.0, 2.0], &[(RowKind::Unilateral, 1), (friction, 0)]);
        assert!((rows.delassus[0] - 0.5).abs() < 1e-15);
        rows.finish(0, None, 1.0, 0.0);
        rows.finish(1, None, 1.0, 0.0);
        rows.warm_start(&[3.0, -1.0]);
        rows.solve(20, 1e-12);
        assert!((rows.impulse(0) - 2.0).abs() < 1e-5, "{}", rows.impulse(0));
        // The hard row's 1e-6 regulariser leaves the normal impulse 1e-6 short.
        assert!((rows.impulse(1) + 1.0).abs() < 1e-5, "{}", rows.impulse(1));
        assert!((rows.velocity[1] - 2.5).abs() < 1e-5);
    }
}
