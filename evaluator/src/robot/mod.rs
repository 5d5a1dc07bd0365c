//! The Panda as D3IL drives it: model constants, the Cartesian IK tracking
//! controller, the joint PD, the finger law (docs/original-d3il.md §01.3).

pub mod control;
pub mod kinematics;

/// Which robot file a task uses (docs/original-d3il.md §01.2.1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RobotVariant {
    /// Gripper plus rod: Avoiding, Aligning, Pushing, Sorting, Inserting.
    Rod,
    /// Gripper without rod: Stacking.
    Gripper,
}

/// Scene initial arm configuration written before the beam to `init_qpos`
/// (docs/original-d3il.md §01.4.4 step 3).
pub const Q_SCENE: [f64; 7] = [
    3.57795216e-09,
    0.174532920,
    3.30500960e-08,
    -0.872664630,
    -1.14096181e-07,
    1.22173047,
    0.785398126,
];

/// Per-task `init_qpos` constants from the reference's start-up IK (docs/original-d3il.md §01.4.5).
pub mod init_qpos {
    /// Avoiding, Pushing, Inserting: TCP target (0.525, -0.28, 0.12).
    pub const AVOIDING: [f64; 7] = [
        -0.356408684719,
        0.429445454037,
        -0.135010595301,
        -2.054651893021,
        0.093578222916,
        2.480717940701,
        0.232506758849,
    ];
    /// Aligning: TCP target (0.525, -0.35, 0.25).
    pub const ALIGNING: [f64; 7] = [
        -0.392758359871,
        0.321778123396,
        -0.212502852524,
        -1.843581356712,
        0.083148880386,
        2.160344058282,
        0.144795218197,
    ];
    /// Sorting: TCP target (0.525, -0.30, 0.25).
    pub const SORTING: [f64; 7] = [
        -0.326826625791,
        0.245625661929,
        -0.203252767156,
        -1.952193734597,
        0.063150520371,
        2.195506134794,
        0.224575845050,
    ];
    /// Stacking: TCP target (0.525, 0.0, 0.30).
    pub const STACKING: [f64; 7] = [
        -1.1708e-08,
        -0.043618586668,
        1.3201e-08,
        -2.188421166999,
        -5.947e-09,
        2.149904161054,
        0.785398167212,
    ];
}
