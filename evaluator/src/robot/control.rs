//! Controllers recomputed at every 1 ms physics substep (docs/original-d3il.md §01.3).

use super::kinematics::{Jacobian, PandaKinematics};
use nalgebra::{SMatrix, SVector, Vector3};

type V6 = SVector<f64, 6>;
type V7 = SVector<f64, 7>;
type M6 = SMatrix<f64, 6, 6>;

/// Joint PD gains (docs/original-d3il.md §01.3.2).
pub const KP: [f64; 7] = [120.0, 120.0, 120.0, 120.0, 50.0, 30.0, 10.0];
pub const KD: [f64; 7] = [10.0, 10.0, 10.0, 10.0, 6.0, 5.0, 3.0];
/// Cartesian gains (docs/original-d3il.md §01.3.2): position (200, 200, 800), orientation 30.
const KX: [f64; 3] = [200.0, 200.0, 800.0];
const KO: f64 = 30.0;
const NULL_GAIN: f64 = 40.0;
const Q_REST: [f64; 7] = [0.0, 0.174, 0.0, -0.872, 0.0, 1.222, 0.785];
const LAMBDA: f64 = 1e-12;
const SV_MIN: f64 = 0.01;
const SV_MAX: f64 = 100.0;
const IK_ITERATIONS: usize = 3;
const IK_STEP: f64 = 0.001;
const POS_ERR_CLIP: f64 = 0.01;
const ORI_ERR_CLIP: f64 = 0.1;
const NULL_CLIP: f64 = 0.2;
const QDOT_NORM_MAX: f64 = 3.0;
/// The robot's software limits used by the IK clip (not the MJCF ranges; q3 <= 2.0).
pub const Q_MIN: [f64; 7] = [
    -2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973,
];
pub const Q_MAX: [f64; 7] = [2.8973, 1.7628, 2.0, -0.0698, 2.8973, 3.7525, 2.8973];
/// Physics time step used for the velocity reference.
pub const H: f64 = 0.001;

/// Orientation error e_o(c, d) = c_w d_v - d_w c_v + c_v x d_v (docs/original-d3il.md §01.3.3).
pub fn orientation_error(c: &[f64; 4], d: &[f64; 4]) -> Vector3<f64> {
    let cv = Vector3::new(c[1], c[2], c[3]);
    let dv = Vector3::new(d[1], d[2], d[3]);
    dv * c[0] - cv * d[0] + cv.cross(&dv)
}

fn quat_dist(a: &[f64; 4], b: &[f64; 4], sign: f64) -> f64 {
    (0..4)
        .map(|i| (a[i] - sign * b[i]).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// Solves (J Jᵀ + λI) x = rhs with the eigenvalues of the matrix clipped to
/// [0.01, 100] (docs/original-d3il.md §01.3.4 step 5). A is symmetric PSD, so SVD clipping
/// equals eigenvalue clipping. Fast path, exact up to round-off: λ_max ≤ trace
/// ≤ 100, and a Cholesky factorisation of A − 0.01·I proves λ_min > 0.01, so
/// nothing is clipped and a Cholesky solve of A suffices.
fn clipped_solve(a: &M6, rhs: &V6) -> V6 {
    if a.trace() <= SV_MAX && (a - M6::identity() * SV_MIN).cholesky().is_some() {
        if let Some(ch) = a.cholesky() {
            return ch.solve(rhs);
        }
    }
    let eig = a.symmetric_eigen();
    let inv = eig.eigenvalues.map(|l| 1.0 / l.clamp(SV_MIN, SV_MAX));
    eig.eigenvectors * M6::from_diagonal(&inv) * (eig.eigenvectors.transpose() * rhs)
}

/// The Cartesian position+quaternion tracking controller of the rod tasks
/// (docs/original-d3il.md §01.3.4): an IK integrator started from its own previous solution.
#[derive(Debug, Clone)]
pub struct CartesianTracker {
    pub x_d: [f64; 3],
    pub quat_d: [f64; 4],
    /// Previous IK solution q̂; None until the first substep of the episode.
    q_hat: Option<[f64; 7]>,
}

impl CartesianTracker {
    pub fn new() -> Self {
        CartesianTracker {
            x_d: [f64::NAN; 3],
            quat_d: [f64::NAN; 4],
            q_hat: None,
        }
    }

    /// Sets the target of this env step; the quaternion is normalised.
    pub fn set_target(&mut self, pos: [f64; 3], quat: [f64; 4]) {
        let n = quat.iter().map(|v| v * v).sum::<f64>().sqrt();
        self.x_d = pos;
        self.quat_d = quat.map(|v| v / n);
    }

    /// One substep of IK: returns (q_d, q̇_d).
    pub fn desired(&mut self, kin: &PandaKinematics, q_meas: &[f64; 7]) -> ([f64; 7], [f64; 7]) {
        let q_prev = self.q_hat.unwrap_or(*q_meas);
        let mut q = V7::from_column_slice(&q_prev);
        let mut qd = self.quat_d;
        let q_rest = V7::from_column_slice(&Q_REST);
        for _ in 0..IK_ITERATIONS {
            let qa: [f64; 7] = q.into();
            let fk = kin.fk(&qa);
            let cur = fk.quat_wxyz();
            if quat_dist(&cur, &qd, 1.0) > quat_dist(&cur, &qd, -1.0) {
                qd = qd.map(|v| -v);
            }
            let ex = (Vector3::from_column_slice(&self.x_d) - fk.pos)
                .map(|e| e.clamp(-POS_ERR_CLIP, POS_ERR_CLIP));
            let eo = orientation_error(&cur, &qd).map(|e| e.clamp(-ORI_ERR_CLIP, ORI_ERR_CLIP));
            let v = V6::new(
                KX[0] * ex[0],
                KX[1] * ex[1],
                KX[2] * ex[2],
                KO * eo[0],
                KO * eo[1],
                KO * eo[2],
            );
            let j: Jacobian = fk.jacobian();
            let a = j * j.transpose() + M6::identity() * LAMBDA;
            let qdot0 = (q_rest - q).map(|e| NULL_GAIN * e.clamp(-NULL_CLIP, NULL_CLIP));
            let mut qdot = j.transpose() * clipped_solve(&a, &(v - j * qdot0)) + qdot0;
            let norm = qdot.norm();
            if norm > QDOT_NORM_MAX {
                qdot *= QDOT_NORM_MAX / norm;
            }
            q += qdot * IK_STEP;
            for i in 0..7 {
                q[i] = q[i].clamp(Q_MIN[i], Q_MAX[i]);
            }
        }
        let q_d: [f64; 7] = q.into();
        let mut qdot_d = [0.0; 7];
        for i in 0..7 {
            qdot_d[i] = (q_d[i] - q_prev[i]) / H;
        }
        self.q_hat = Some(q_d);
        (q_d, qdot_d)
    }
}

impl Default for CartesianTracker {
    fn default() -> Self {
        Self::new()
    }
}

/// Plain joint PD: τ = K_P (q_d − q) + K_D (q̇_d − q̇) (docs/original-d3il.md §01.3.4 step 5, §01.3.6).
pub fn joint_pd(q_d: &[f64; 7], qdot_d: &[f64; 7], q: &[f64; 7], qdot: &[f64; 7]) -> [f64; 7] {
    let mut tau = [0.0; 7];
    let scale = drift_test_kp_scale();
    for i in 0..7 {
        tau[i] = KP[i] * scale * (q_d[i] - q[i]) + KD[i] * (qdot_d[i] - qdot[i]);
    }
    tau
}

/// A deliberate drift, for the test that the drift canary (`d3il verify`)
/// catches a changed controller: `D3IL_DRIFT_TEST_KP_SCALE` scales the joint
/// P gains. Unset, as always outside that test, the scale is 1.0 and the
/// torques are bit for bit those of `KP` (x × 1.0 = x exactly).
fn drift_test_kp_scale() -> f64 {
    static SCALE: std::sync::OnceLock<f64> = std::sync::OnceLock::new();
    *SCALE.get_or_init(|| {
        std::env::var("D3IL_DRIFT_TEST_KP_SCALE")
            .ok()
            .and_then(|v| v.parse().ok())
            .unwrap_or(1.0)
    })
}

/// Finger command: per-finger target width w and the grasp flag g (docs/original-d3il.md §01.3.7).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FingerCommand {
    pub target: f64,
    pub grasp: bool,
}

impl FingerCommand {
    /// Reset default: w = 0.001, g = false.
    pub const RESET: FingerCommand = FingerCommand {
        target: 0.001,
        grasp: false,
    };
    /// "open": w = 0.04, g = false.
    pub const OPEN: FingerCommand = FingerCommand {
        target: 0.04,
        grasp: false,
    };
    /// "close": w = 0, g = true.
    pub const CLOSE: FingerCommand = FingerCommand {
        target: 0.0,
        grasp: true,
    };
}

/// Finger force law (docs/original-d3il.md §01.3.7); no bias is added.
pub fn finger_forces(cmd: FingerCommand, p: [f64; 2], pdot: [f64; 2]) -> [f64; 2] {
    let mean = 0.5 * (p[0] + p[1]);
    let mut f = [0.0; 2];
    for i in 0..2 {
        let f2 = if mean - cmd.target > 0.005 {
            if cmd.grasp {
                -20.0
            } else {
                10.0 * (-0.2 - pdot[i])
            }
        } else {
            (500.0 * (cmd.target - p[i]) - 10.0 * pdot[i]).clamp(-5.0, 5.0)
        };
        f[i] = 500.0 * (mean - p[i]) + f2;
    }
    f
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clipped_solve_matches_eigen_clipping_on_both_paths() {
        let reference = |a: &M6, rhs: &V6| {
            let eig = a.symmetric_eigen();
            let inv = eig.eigenvalues.map(|l| 1.0 / l.clamp(SV_MIN, SV_MAX));
            eig.eigenvectors * M6::from_diagonal(&inv) * eig.eigenvectors.transpose() * rhs
        };
        let kin = PandaKinematics::new();
        let rhs = V6::new(1.0, -2.0, 0.5, 0.1, 0.2, -0.3);
        // A comfortable pose (no clipping) and a far-reach pose whose smallest
        // eigenvalue falls below 0.01 (clipping active, docs/original-d3il.md §01.3.4).
        for q in [
            crate::robot::init_qpos::AVOIDING,
            [0.0, 1.5, 0.0, -0.1, 0.0, 1.6, 0.785],
        ] {
            let j = kin.fk(&q).jacobian();
            let a = j * j.transpose() + M6::identity() * LAMBDA;
            let got = clipped_solve(&a, &rhs);
            let want = reference(&a, &rhs);
            assert!(
                (got - want).norm() < 1e-9 * want.norm().max(1.0),
                "{got} vs {want}"
            );
        }
        let j = kin.fk(&[0.0, 1.5, 0.0, -0.1, 0.0, 1.6, 0.785]).jacobian();
        let a = j * j.transpose();
        assert!(
            a.symmetric_eigen().eigenvalues.min() < SV_MIN,
            "far pose must exercise clipping"
        );
    }

    #[test]
    fn orientation_error_is_sign_invariant_and_half_angle() {
        let c = [0.0, 1.0, 0.0, 0.0];
        let small = 0.01_f64;
        // d = rotation of c by `small` about world z.
        let d = [
            -(small / 2.0).sin() * 0.0,
            (small / 2.0).cos(),
            (small / 2.0).sin(),
            0.0,
        ];
        let e = orientation_error(&c, &d);
        let e_neg = orientation_error(&c.map(|v| -v), &d.map(|v| -v));
        assert!((e - e_neg).norm() < 1e-15);
        assert!((e.norm() - (small / 2.0).sin()).abs() < 1e-12, "{e}");
    }
}
