//! The fidelity report (`d3il fidelity`, the server's `/fidelity` page): how
//! closely this simulator follows the original D3IL one, measured on the
//! data recorded in the original (docs/fidelity.md). Plain data: the
//! evaluator computes it, the server only shows it.

use serde::{Deserialize, Serialize};

/// The `format` of a report this build writes.
pub const FIDELITY_FORMAT: &str = "d3il-fidelity/1";

/// How much of the closed-loop protocol a report ran.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum FidelityMode {
    /// The paper protocol for every closed-loop policy (minutes).
    Full,
    /// The quick protocol (3 initial states × 2 rollouts) for the
    /// closed-loop policies; everything else as in `Full` (seconds).
    Quick,
}

impl FidelityMode {
    pub fn as_str(self) -> &'static str {
        match self {
            FidelityMode::Full => "full",
            FidelityMode::Quick => "quick",
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FidelityReport {
    pub format: String,
    pub mode: FidelityMode,
    /// `d3il --version` of the build that computed it.
    pub d3il_version: String,
    pub mujoco_version: String,
    /// Unix seconds when it was finished, and how long it took.
    pub generated_unix: i64,
    pub seconds: f64,
    pub episodes: EpisodesSection,
    pub closed_loop: ClosedLoopSection,
    pub frames: FramesSection,
    pub deviations: Vec<Deviation>,
}

// ------------------------------------------------------------ (a) episodes

/// The episodes recorded in the original, replayed open-loop here.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodesSection {
    /// A reference object counts as moved (contact has begun) once it is
    /// this far (m, xy) from where it started.
    pub contact_motion_m: f64,
    /// Two runs "stay together" while every TCP and object position is
    /// within this distance (m).
    pub together_m: f64,
    pub episodes: Vec<EpisodeFidelity>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpisodeFidelity {
    pub task: String,
    /// Path under the reference-rollouts directory.
    pub file: String,
    pub description: String,
    pub steps_original: usize,
    pub steps_here: usize,
    pub success_original: bool,
    pub success_here: bool,
    pub behaviour_original: serde_json::Value,
    pub behaviour_here: serde_json::Value,
    /// Env steps before the first reference object moves (the whole
    /// episode when none does).
    pub free_motion_steps: usize,
    /// Largest TCP distance from the original's over those steps (m).
    pub free_motion_tcp_max_m: f64,
    /// The contact phase, when a reference object moves.
    pub contact: Option<ContactPhase>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ContactPhase {
    /// The env step at which the first reference object has moved.
    pub starts_at: usize,
    /// Steps after `starts_at` that our replay stays together with the
    /// original (None: until the end of the episode).
    pub with_original: Option<usize>,
    /// Steps after `starts_at` that our replay with qpos[0] changed by one
    /// ulp after reset stays together with our unchanged replay (None:
    /// until the end): how long any two runs this close can be expected to
    /// stay together.
    pub one_ulp: Option<usize>,
    /// Steps after `starts_at` to the end of the episode.
    pub remaining: usize,
    /// Largest distance of a reference object's final xy from ours (m).
    pub final_object_xy_m: f64,
}

// --------------------------------------------------------- (b) closed loop

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ClosedLoopSection {
    /// `paper` or `quick`: the protocol the policies were evaluated under here.
    pub protocol: String,
    /// Tolerance of the open-loop replays of the original's actions (m).
    pub tcp_tolerance_m: f64,
    pub policies: Vec<PolicyFidelity>,
}

/// A success rate with its 95 % interval.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Rate {
    pub successes: usize,
    pub rollouts: usize,
    pub value: f64,
    pub ci_low: f64,
    pub ci_high: f64,
    /// How the interval was computed.
    pub interval: String,
}

impl Rate {
    pub fn contains(&self, x: f64) -> bool {
        self.ci_low <= x && x <= self.ci_high
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PolicyFidelity {
    pub name: String,
    pub task: String,
    pub description: String,
    /// Initial states compared (the original ran one rollout on each).
    pub contexts: usize,
    pub rollouts_per_context_here: usize,
    /// Over the compared initial states.
    pub original: Rate,
    pub here: Rate,
    pub here_inside_original_interval: bool,
    pub original_inside_here_interval: bool,
    /// Share of our rollouts whose success equals the original rollout's
    /// in the same initial state (for a deterministic policy: the share of
    /// initial states with the same outcome).
    pub success_agreement: f64,
    /// The same for the behaviour label.
    pub behaviour_agreement: f64,
    pub per_context: Vec<ContextAgreement>,
    /// The original's actions replayed open-loop here, one per compared
    /// initial state.
    pub open_loop: Vec<OpenLoopEpisode>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ContextAgreement {
    pub context: usize,
    pub original_success: bool,
    pub original_behaviour: serde_json::Value,
    pub original_steps: usize,
    pub here_successes: usize,
    pub here_rollouts: usize,
    /// Our rollouts with the original's behaviour label.
    pub here_same_behaviour: usize,
    pub here_mean_steps: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OpenLoopEpisode {
    pub context: usize,
    pub steps_original: usize,
    /// Env steps from reset during which our TCP stays within the
    /// tolerance of the original's (every row 0..=n).
    pub steps_within: usize,
    /// `steps_within` reaches the end of the original's episode.
    pub whole_episode: bool,
    /// Largest TCP distance over those steps (m).
    pub max_within_m: f64,
    /// Our closed-loop rollout 0 in this state ended like the original's.
    pub closed_loop_same_success: bool,
    /// The replay ended like the original (success and steps).
    pub replay_same_success: bool,
}

// -------------------------------------------------------------- (c) frames

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FramesSection {
    /// How our robot was drawn (`meshes` or `primitives`).
    pub robot_look: String,
    /// A channel counts as "off" when it differs by more than this (/255).
    pub off_threshold: u8,
    pub frames: Vec<FrameFidelity>,
    /// Per camera, averaged over the frames.
    pub cameras: Vec<CameraSummary>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameFidelity {
    pub task: String,
    pub context: usize,
    /// `front` (bp_cam) or `inhand` (rgbd_rb0).
    pub camera: String,
    /// Mean absolute difference over all pixels and channels, in units of 1/255.
    pub mean_abs: f64,
    /// Share of pixels with a channel off by more than the threshold.
    pub share_off: f64,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CameraSummary {
    pub camera: String,
    pub frames: usize,
    pub mean_abs: f64,
    pub max_mean_abs: f64,
    pub share_off: f64,
}

// ---------------------------------------------------------- (d) deviations

/// A known difference from the original and what it can do to a number.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Deviation {
    pub what: String,
    /// Where it is documented.
    pub source: String,
    /// What it can change in a reported number, and by how much when known.
    pub effect: String,
}
