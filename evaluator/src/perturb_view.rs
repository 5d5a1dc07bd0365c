//! The image axes of the robustness suites (docs/robustness.md):
//! what `camera` and `lighting` change in a freshly compiled scene, before
//! any renderer is made from it (a renderer copies its model, and the
//! engine's renderer is keyed by the model it draws).
//!
//! * `camera`: every listed camera moved by `camera_shift_m` along its own
//!   axes and then turned by `camera_turn_deg` about its own x, y and z axes
//!   (intrinsic, in that order): `pos' = pos + R(quat)·shift`, `quat' = quat
//!   ⊗ q_x ⊗ q_y ⊗ q_z`. The in-hand camera moves with the hand as before,
//!   from its new mount.
//! * `lighting`: every light's ambient, diffuse and specular colour scaled
//!   by `light_scale`, and its direction turned by `light_tilt_deg` about the
//!   world's y axis.
//!
//! A zero setting (no shift, no turn; scale 1, no tilt) leaves every value
//! as compiled to the bit.

use crate::mujoco::{MjError, Model, ObjKind};
use d3il_protocol::perturbation::LevelSetting;

/// Changes `model`'s `cameras` and lights as `setting` says.
pub fn apply(model: &mut Model, cameras: &[String], setting: &LevelSetting) -> Result<(), MjError> {
    let shift = setting.camera_shift_m.unwrap_or([0.0; 3]);
    let turn = setting.camera_turn_deg.unwrap_or([0.0; 3]);
    let mut moved = vec![];
    if shift != [0.0; 3] || turn != [0.0; 3] {
        for name in cameras {
            let id = model.id(ObjKind::Camera, name)?;
            let (pos, quat) = model.cam_local_pose(id);
            moved.push((id, moved_pos(pos, quat, shift), turned_quat(quat, turn)));
        }
    }
    let scale = setting.light_scale.unwrap_or(1.0) as f32;
    let tilt = setting.light_tilt_deg.unwrap_or(0.0).to_radians();
    model.perturb_view(&moved, scale, &|d| {
        if tilt == 0.0 {
            d
        } else {
            tilt_about_y(d, tilt)
        }
    })
}

/// `pos + R(quat)·shift`: a camera moved along its own axes.
pub fn moved_pos(pos: [f64; 3], quat: [f64; 4], shift: [f64; 3]) -> [f64; 3] {
    let r = rotate(quat, shift);
    [pos[0] + r[0], pos[1] + r[1], pos[2] + r[2]]
}

/// `quat ⊗ q_x(a) ⊗ q_y(b) ⊗ q_z(c)` (angles in degrees), normalised.
pub fn turned_quat(quat: [f64; 4], turn_deg: [f64; 3]) -> [f64; 4] {
    let mut q = quat;
    for (axis, deg) in turn_deg.into_iter().enumerate() {
        let h = 0.5 * deg.to_radians();
        let mut r = [h.cos(), 0.0, 0.0, 0.0];
        r[axis + 1] = h.sin();
        q = mul(q, r);
    }
    let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
    q.map(|v| v / n)
}

/// `d` turned by `angle` (radians) about the world's y axis.
pub fn tilt_about_y(d: [f64; 3], angle: f64) -> [f64; 3] {
    let (s, c) = angle.sin_cos();
    [c * d[0] + s * d[2], d[1], -s * d[0] + c * d[2]]
}

/// Hamilton product of (w, x, y, z) quaternions.
fn mul(a: [f64; 4], b: [f64; 4]) -> [f64; 4] {
    [
        a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3],
        a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
        a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1],
        a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0],
    ]
}

/// The rotation matrix of a unit quaternion, row-major.
pub fn quat_mat(q: [f64; 4]) -> [f64; 9] {
    let [w, x, y, z] = q;
    [
        1.0 - 2.0 * (y * y + z * z),
        2.0 * (x * y - w * z),
        2.0 * (x * z + w * y),
        2.0 * (x * y + w * z),
        1.0 - 2.0 * (x * x + z * z),
        2.0 * (y * z - w * x),
        2.0 * (x * z - w * y),
        2.0 * (y * z + w * x),
        1.0 - 2.0 * (x * x + y * y),
    ]
}

fn rotate(q: [f64; 4], v: [f64; 3]) -> [f64; 3] {
    let m = quat_mat(q);
    [0, 1, 2].map(|i| m[3 * i] * v[0] + m[3 * i + 1] * v[1] + m[3 * i + 2] * v[2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_turn_about_each_own_axis_composes_in_order() {
        let q = turned_quat([1.0, 0.0, 0.0, 0.0], [90.0, 0.0, 0.0]);
        let m = quat_mat(q);
        // About x by 90°: y -> z.
        assert!((m[7] - 1.0).abs() < 1e-12 && m[4].abs() < 1e-12);
        let p = moved_pos([1.0, 2.0, 3.0], q, [0.0, 1.0, 0.0]);
        assert!((p[0] - 1.0).abs() < 1e-12 && (p[1] - 2.0).abs() < 1e-12);
        assert!((p[2] - 4.0).abs() < 1e-12);
        let d = tilt_about_y([0.0, 0.0, -1.0], 30f64.to_radians());
        assert!(
            (d[0] + 0.5).abs() < 1e-12,
            "a positive tilt points towards −x"
        );
    }
}
