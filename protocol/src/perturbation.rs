//! The robustness track: perturbation suites, the perturbation a
//! result was evaluated under (recorded in its protocol manifest, so that its
//! rollouts replay); the document `d3il eval --suite` writes is
//! [`crate::robustness`].
//!
//! A suite is a fixed, versioned file per task (`assets/robustness/`, sha256
//! checked at load like the initial-state sets). It has axes, each with
//! levels; level 0 of every axis is the standard protocol, which is the
//! control arm: every level runs on the same initial states, with the same
//! seed and rollout ids (so the same policy noise), and its drop is a paired
//! difference against level 0.

use serde::{Deserialize, Serialize};

/// The axes of a suite.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Axis {
    /// Object start poses pushed outwards: each sampled coordinate of the
    /// initial state moved away from the centre of the task's sampling range
    /// by the level's fraction (the range widened by it).
    StartShift,
    /// Gaussian noise on the state observation, in task units.
    ObsNoise,
    /// Each action applied a number of environment steps late.
    Latency,
    /// Box mass and box–table friction scaled.
    Dynamics,
    /// Image policies: the cameras moved and turned in their own frames.
    Camera,
    /// Image policies: the scene's lights dimmed and tilted.
    Lighting,
}

impl Axis {
    pub const ALL: [Axis; 6] = [
        Axis::StartShift,
        Axis::ObsNoise,
        Axis::Latency,
        Axis::Dynamics,
        Axis::Camera,
        Axis::Lighting,
    ];

    pub fn as_str(self) -> &'static str {
        match self {
            Axis::StartShift => "start_shift",
            Axis::ObsNoise => "obs_noise",
            Axis::Latency => "latency",
            Axis::Dynamics => "dynamics",
            Axis::Camera => "camera",
            Axis::Lighting => "lighting",
        }
    }
}

impl std::fmt::Display for Axis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for Axis {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Axis::ALL
            .into_iter()
            .find(|a| a.as_str() == s)
            .ok_or_else(|| {
                format!(
                    "unknown axis `{s}`; the axes are {}",
                    Axis::ALL.map(Axis::as_str).join(", ")
                )
            })
    }
}

/// One level of an axis as the suite file states it. Only the fields of the
/// level's axis are set.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct LevelSetting {
    /// Short human label, e.g. `+50 %`, `5 mm / 2.9°`, `2 steps`, `mass ×2`.
    pub label: String,
    /// start_shift: fraction by which each sampling range is widened
    /// (0.5 = +50 %: a coordinate at the range's edge moves half a
    /// half-width further out).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub widen: Option<f64>,
    /// obs_noise: standard deviation on positions, metres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub position_m: Option<f64>,
    /// obs_noise: standard deviation on yaw angles, radians.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub angle_rad: Option<f64>,
    /// latency: env steps between the policy's action and its application.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steps: Option<usize>,
    /// latency: a further fraction `f` of a step (0 < f < 1, suites v2 on):
    /// the environment receives `(1 − f)·a(t − steps) + f·a(t − steps − 1)`,
    /// the zero-order hold of a command that arrives `f` of a step later.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub fraction: Option<f64>,
    /// dynamics: factor on the boxes' mass (and inertia).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mass: Option<f64>,
    /// dynamics: factor on the box–table sliding friction.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction: Option<f64>,
    /// camera: each camera moved by this offset (metres) along its own axes
    /// (MuJoCo's camera frame: x right, y up, z backwards out of the view).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_shift_m: Option<[f64; 3]>,
    /// camera: each camera then turned by these angles (degrees) about its
    /// own x, y and z axes, in that order (intrinsic).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_turn_deg: Option<[f64; 3]>,
    /// lighting: factor on every light's diffuse, specular and ambient
    /// colour.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light_scale: Option<f64>,
    /// lighting: every light's direction turned by this angle (degrees)
    /// about the world's y axis (towards −x, the robot, for a positive
    /// angle: the scene's one light is directional and points down).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub light_tilt_deg: Option<f64>,
}

/// The perturbation a result was evaluated under (its protocol manifest's
/// `perturbation`; absent for a plain evaluation, i.e. level 0). With the
/// suite file it names, it is everything a replay needs besides the record.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Perturbation {
    /// The suite file, e.g. `aligning-v1.json` (in `assets/robustness/`).
    pub suite: String,
    pub suite_sha256: String,
    pub axis: Axis,
    /// 1-based; level 0 is the standard protocol and has no perturbation.
    pub level: usize,
    pub setting: LevelSetting,
}
