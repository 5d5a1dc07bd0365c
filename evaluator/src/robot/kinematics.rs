//! Exact forward kinematics and TCP Jacobian of the Panda as the reference's
//! controllers compute them (Pinocchio on the URDF, frame `panda_grasptarget`,
//! docs/original-d3il.md §01.2.8). Using the exact URDF angles instead of MuJoCo's kinematics of
//! the MJCF (whose hand quaternion is rounded) reproduces the reference to ~1e-16.

use nalgebra::{Matrix3, Rotation3, SMatrix, UnitQuaternion, Vector3};

pub type Jacobian = SMatrix<f64, 6, 7>;

/// Joint origins (xyz; rpy) of the URDF chain, each followed by a rotation
/// about the local z axis (docs/original-d3il.md §01.2.8 table).
const JOINT_XYZ: [[f64; 3]; 7] = [
    [0.0, 0.0, 0.333],
    [0.0, 0.0, 0.0],
    [0.0, -0.316, 0.0],
    [0.0825, 0.0, 0.0],
    [-0.0825, 0.384, 0.0],
    [0.0, 0.0, 0.0],
    [0.088, 0.0, 0.0],
];
// These are the URDF's printed (rounded) angles, not π/2 and π/4: the reference
// kinematics use exactly these values (docs/original-d3il.md §01.2.8).
#[allow(clippy::approx_constant)]
const JOINT_ROLL: [f64; 7] = [
    0.0,
    -1.57079632679,
    1.57079632679,
    1.57079632679,
    -1.57079632679,
    1.57079632679,
    1.57079632679,
];
/// Flange (link8) offset, hand yaw and grasp-target offset (docs/original-d3il.md §01.2.8).
const FLANGE_Z: f64 = 0.107;
#[allow(clippy::approx_constant)]
const HAND_YAW: f64 = -0.785398163397;
const GRASP_Z: f64 = 0.105;

/// Precomputed constant rotations, so FK costs only the joint-angle trig.
#[derive(Debug, Clone)]
pub struct PandaKinematics {
    joint_rot: [Matrix3<f64>; 7],
    hand_rot: Matrix3<f64>,
}

impl Default for PandaKinematics {
    fn default() -> Self {
        Self::new()
    }
}

/// Result of FK: TCP position, TCP rotation, and per-joint world axes/origins.
pub struct Fk {
    pub pos: Vector3<f64>,
    pub rot: Matrix3<f64>,
    axes: [Vector3<f64>; 7],
    origins: [Vector3<f64>; 7],
}

impl PandaKinematics {
    pub fn new() -> Self {
        let joint_rot = JOINT_ROLL.map(|r| {
            // URDF rpy = Rz(y) Ry(p) Rx(r); only roll is non-zero here.
            *Rotation3::from_axis_angle(&Vector3::x_axis(), r).matrix()
        });
        let hand_rot = *Rotation3::from_axis_angle(&Vector3::z_axis(), HAND_YAW).matrix();
        PandaKinematics {
            joint_rot,
            hand_rot,
        }
    }

    /// Forward kinematics of the grasp target (our TCP) for arm angles `q`.
    pub fn fk(&self, q: &[f64; 7]) -> Fk {
        let mut rot = Matrix3::identity();
        let mut pos = Vector3::zeros();
        let mut axes = [Vector3::zeros(); 7];
        let mut origins = [Vector3::zeros(); 7];
        for i in 0..7 {
            let xyz = JOINT_XYZ[i];
            pos += rot * Vector3::new(xyz[0], xyz[1], xyz[2]);
            rot *= self.joint_rot[i];
            let (s, c) = q[i].sin_cos();
            let rz = Matrix3::new(c, -s, 0.0, s, c, 0.0, 0.0, 0.0, 1.0);
            rot *= rz;
            axes[i] = rot.column(2).into_owned();
            origins[i] = pos;
        }
        pos += rot * Vector3::new(0.0, 0.0, FLANGE_Z);
        rot *= self.hand_rot;
        pos += rot * Vector3::new(0.0, 0.0, GRASP_Z);
        Fk {
            pos,
            rot,
            axes,
            origins,
        }
    }
}

impl Fk {
    /// TCP orientation as a quaternion (w, x, y, z). The sign is irrelevant to
    /// the controller (docs/original-d3il.md §01.2.8, §01.3.3).
    pub fn quat_wxyz(&self) -> [f64; 4] {
        // Direct (Shepperd/Eigen-style) conversion: `rot` is orthonormal by
        // construction, so nalgebra's iterative `from_matrix` is not needed.
        let q = UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(self.rot));
        [q.w, q.i, q.j, q.k]
    }

    /// 6x7 Jacobian in the world-aligned frame at the TCP: rows 0-2 linear,
    /// rows 3-5 angular velocity (docs/original-d3il.md §01.2.8).
    pub fn jacobian(&self) -> Jacobian {
        let mut j = Jacobian::zeros();
        for i in 0..7 {
            let lin = self.axes[i].cross(&(self.pos - self.origins[i]));
            for r in 0..3 {
                j[(r, i)] = lin[r];
                j[(r + 3, i)] = self.axes[i][r];
            }
        }
        j
    }
}
