//! docs/original-d3il.md §01.8 "Test A": Avoiding hold, then step.

use super::scene::SceneSpec;
use super::*;
use crate::robot::{init_qpos, RobotVariant};

fn bare_rod_sim() -> Sim {
    let model = Arc::new(SceneSpec::new(RobotVariant::Rod).compile().unwrap());
    let ids = Arc::new(RobotIds::lookup(&model).unwrap());
    Sim::new(model, ids, 35).unwrap()
}

const Z0: f64 = 0.122359305991;
const QUAT_DOWN: [f64; 4] = [0.0, 1.0, 0.0, 0.0];

/// (step, x, y, z) rows of docs/original-d3il.md §01.8.
const TCP_ROWS: [(usize, [f64; 3]); 11] = [
    (0, [0.524928466, -0.279736728, 0.122359306]),
    (1, [0.527391345, -0.276939761, 0.122808764]),
    (2, [0.527556312, -0.277321468, 0.123610431]),
    (3, [0.527429411, -0.278203453, 0.124290654]),
    (5, [0.527123030, -0.279864680, 0.125150210]),
    (10, [0.525678095, -0.282201811, 0.124684327]),
    (11, [0.514489264, -0.276200666, 0.123796949]),
    (12, [0.503922645, -0.258571570, 0.122768088]),
    (13, [0.500578778, -0.242759975, 0.122228255]),
    (15, [0.507465455, -0.218701597, 0.121958927]),
    (20, [0.531948874, -0.178726410, 0.121774527]),
];
const FINGERS: [(usize, f64, f64); 6] = [
    (0, 2.29e-5, 2.29e-5),
    (1, 0.015866, 0.016138),
    (2, 0.030042, 0.030144),
    (3, 0.036015, 0.036032),
    (5, 0.039361, 0.039358),
    (10, 0.039995, 0.039991),
];
const JOINTS_10: [f64; 7] = [
    -0.41999458,
    0.425227924,
    -0.073605311,
    -2.051083053,
    0.048849179,
    2.480547687,
    0.261997662,
];
const JOINTS_20: [f64; 7] = [
    -0.254905847,
    0.351757395,
    -0.068931859,
    -2.180057615,
    0.052691416,
    2.527560040,
    0.396449759,
];

#[test]
fn test_a_avoiding_hold_then_step() {
    let mut sim = bare_rod_sim();
    sim.reset(&init_qpos::AVOIDING, FingerCommand::RESET, |_| {})
        .unwrap();
    let mut tcp = vec![sim.tcp_pos()];
    let mut fingers = vec![sim.finger_pos()];
    let mut joints = vec![sim.joint_pos()];
    let mut observations = Vec::new();
    for step in 1..=20 {
        let y = if step <= 10 { -0.28 } else { -0.20 };
        // docs/original-d3il.md §01.4.2: fingers open, setpoint, observation BEFORE the physics.
        sim.fingers = FingerCommand::OPEN;
        sim.set_cartesian_target([0.525, y, Z0], QUAT_DOWN);
        let p = sim.tcp_pos();
        observations.push([p[0] as f32, p[1] as f32]);
        sim.step_physics().unwrap();
        tcp.push(sim.tcp_pos());
        fingers.push(sim.finger_pos());
        joints.push(sim.joint_pos());
    }
    for (step, want) in TCP_ROWS {
        for k in 0..3 {
            let err = (tcp[step][k] - want[k]).abs();
            // The table is printed with 9 decimals: allow its rounding plus 1e-6.
            assert!(
                err < 1e-6,
                "step {step} axis {k}: got {} want {} (err {err:e})",
                tcp[step][k],
                want[k]
            );
        }
    }
    for (step, f1, f2) in FINGERS {
        let tol = if step == 0 { 1e-7 } else { 2e-6 };
        assert!(
            (fingers[step][0] - f1).abs() < tol,
            "finger1 at {step}: {:?}",
            fingers[step]
        );
        assert!(
            (fingers[step][1] - f2).abs() < tol,
            "finger2 at {step}: {:?}",
            fingers[step]
        );
    }
    for (step, want) in [(10, JOINTS_10), (20, JOINTS_20)] {
        for i in 0..7 {
            let err = (joints[step][i] - want[i]).abs();
            assert!(
                err < 1e-5,
                "joint {i} after step {step}: {} vs {}",
                joints[step][i],
                want[i]
            );
        }
    }
    // One-step observation lag: obs of step k = TCP after step k-1, as float32.
    for k in 1..=20 {
        assert_eq!(
            observations[k - 1],
            [tcp[k - 1][0] as f32, tcp[k - 1][1] as f32]
        );
    }
    assert_eq!(
        observations[0],
        [0.524928466_f64 as f32, -0.279736728_f64 as f32]
    );
}
