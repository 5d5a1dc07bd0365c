//! Small geometric helpers shared by the tasks.

/// Quaternion (w, x, y, z) of a yaw rotation given in degrees: the
/// repository's Euler->quaternion gives (cos ψ/2, 0, 0, sin ψ/2) (docs/original-d3il.md §01.7.11).
pub fn yaw_deg_to_quat(yaw_deg: f64) -> [f64; 4] {
    let psi = yaw_deg.to_radians();
    [(psi / 2.0).cos(), 0.0, 0.0, (psi / 2.0).sin()]
}

/// Yaw ψ = atan2(2(wz − xy), 1 − 2(y² + z²))-style extraction exactly as the
/// reference: build R normalised by |q|², take −atan2(R01, R00) (docs/original-d3il.md §10.4.3),
/// with the degenerate branch −atan2(−R10, R11).
pub fn quat_to_yaw(q: &[f64; 4]) -> f64 {
    let [w, x, y, z] = *q;
    let n = w * w + x * x + y * y + z * z;
    let s = if n > 0.0 { 2.0 / n } else { 0.0 };
    let r00 = 1.0 - s * (y * y + z * z);
    let r01 = s * (x * y - w * z);
    let r10 = s * (x * y + w * z);
    let r11 = 1.0 - s * (x * x + z * z);
    let r12 = s * (y * z - w * x);
    let r22 = 1.0 - s * (x * x + y * y);
    if (r22 * r22 + r12 * r12).sqrt() > 4.0 * f64::EPSILON {
        -r01.atan2(r00)
    } else {
        -(-r10).atan2(r11)
    }
}

pub fn dist3(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

pub fn dist2(a: &[f64], b: &[f64]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaw_round_trips() {
        for deg in [-89.0, -43.5, 0.0, 12.0, 69.6, 89.9] {
            let q = yaw_deg_to_quat(deg);
            assert!((quat_to_yaw(&q).to_degrees() - deg).abs() < 1e-9, "{deg}");
        }
        // The reference context 0 of Pushing: red quat for 69.603806 deg.
        let q = yaw_deg_to_quat(69.603806);
        assert!((q[0] - 0.82113026).abs() < 1e-7 && (q[3] - 0.57074084).abs() < 1e-7);
    }
}
