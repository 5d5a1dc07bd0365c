use serde::{Deserialize, Serialize};
use std::fmt;
use std::str::FromStr;

/// The simulation's timestep in milliseconds (assets/mjcf/base.xml:
/// `timestep="0.001"`).
pub const TIMESTEP_MS: usize = 1;

/// The D3IL task variants the leaderboard evaluates.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum TaskId {
    Avoiding,
    Aligning,
    Pushing,
    #[serde(rename = "sorting-2")]
    Sorting2,
    #[serde(rename = "sorting-4")]
    Sorting4,
    #[serde(rename = "sorting-6")]
    Sorting6,
    Stacking,
    Inserting,
}

impl TaskId {
    pub const ALL: [TaskId; 8] = [
        TaskId::Avoiding,
        TaskId::Aligning,
        TaskId::Pushing,
        TaskId::Sorting2,
        TaskId::Sorting4,
        TaskId::Sorting6,
        TaskId::Stacking,
        TaskId::Inserting,
    ];

    /// URL/CLI slug, e.g. `sorting-4`.
    pub fn slug(self) -> &'static str {
        match self {
            TaskId::Avoiding => "avoiding",
            TaskId::Aligning => "aligning",
            TaskId::Pushing => "pushing",
            TaskId::Sorting2 => "sorting-2",
            TaskId::Sorting4 => "sorting-4",
            TaskId::Sorting6 => "sorting-6",
            TaskId::Stacking => "stacking",
            TaskId::Inserting => "inserting",
        }
    }

    /// Human title as the paper prints it, e.g. `Sorting-4 (T4)`.
    pub fn title(self) -> &'static str {
        match self {
            TaskId::Avoiding => "Avoiding (T1)",
            TaskId::Aligning => "Aligning (T2)",
            TaskId::Pushing => "Pushing (T3)",
            TaskId::Sorting2 => "Sorting-2 (T4)",
            TaskId::Sorting4 => "Sorting-4 (T4)",
            TaskId::Sorting6 => "Sorting-6 (T4)",
            TaskId::Stacking => "Stacking (T5)",
            TaskId::Inserting => "Inserting (T6)",
        }
    }

    /// Physics steps of one environment step: 35, Stacking 30
    /// (docs/original-d3il.md §11.2.4).
    pub fn substeps(self) -> usize {
        match self {
            TaskId::Stacking => 30,
            _ => 35,
        }
    }

    /// Milliseconds one environment step lasts: [`TaskId::substeps`] of the
    /// model's 1 ms timestep ([`TIMESTEP_MS`]).
    pub fn step_ms(self) -> usize {
        self.substeps() * TIMESTEP_MS
    }

    /// Seconds one environment step lasts (0.035; Stacking 0.030).
    pub fn step_seconds(self) -> f64 {
        self.step_ms() as f64 / 1000.0
    }

    /// Number of behaviours |B| (log base of the entropies).
    pub fn n_behaviours(self) -> usize {
        match self {
            TaskId::Avoiding => 24,
            TaskId::Aligning => 2,
            TaskId::Pushing => 4,
            TaskId::Sorting2 => 2,
            TaskId::Sorting4 => 6,
            TaskId::Sorting6 => 20,
            TaskId::Stacking => 6,
            TaskId::Inserting => 6,
        }
    }

    /// The leaderboard's evaluation protocol for this task, as shown on its
    /// pages. The evaluator's task definitions must agree (tested in
    /// evaluator/tests/simulator/context_sets.rs).
    pub fn paper_protocol(self) -> PaperProtocol {
        let (contexts, rollouts, max_steps) = match self {
            TaskId::Avoiding => (1, 480, 250),
            TaskId::Aligning => (60, 8, 400),
            TaskId::Pushing => (30, 16, 400),
            TaskId::Sorting2 => (60, 18, 500),
            TaskId::Sorting4 => (60, 18, 700),
            TaskId::Sorting6 => (60, 18, 1200),
            TaskId::Stacking => (60, 18, 1000),
            TaskId::Inserting => (60, 8, 2000),
        };
        PaperProtocol {
            contexts,
            rollouts,
            max_steps,
            max_steps_image: match self {
                TaskId::Stacking => Some(1200),
                t if t.has_image_variant() => Some(max_steps),
                _ => None,
            },
            ours: self == TaskId::Inserting,
        }
    }

    /// (initial states, rollouts per initial state) of `protocol` on a set of
    /// `set_len` stored initial states: the paper's protocol uses the first
    /// `contexts` of the set; the quick protocol is a smoke-test subset (the
    /// first few initial states, few rollouts each). The one rule the
    /// evaluator runs and the server shards by.
    pub fn protocol_size(self, protocol: crate::ProtocolKind, set_len: usize) -> (usize, usize) {
        let p = self.paper_protocol();
        let paper = (set_len.min(p.contexts), p.rollouts);
        match protocol {
            crate::ProtocolKind::Paper => paper,
            crate::ProtocolKind::Quick => {
                if paper.0 == 1 {
                    (1, paper.1.min(8))
                } else {
                    (paper.0.min(3), paper.1.min(2))
                }
            }
        }
    }

    /// Whether the paper reports image-based results for this task.
    pub fn has_image_variant(self) -> bool {
        matches!(
            self,
            TaskId::Aligning | TaskId::Sorting4 | TaskId::Sorting6 | TaskId::Stacking
        )
    }
}

impl fmt::Display for TaskId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.slug())
    }
}

#[derive(Debug, thiserror::Error)]
#[error("unknown task `{0}`; expected one of: avoiding, aligning, pushing, sorting-2, sorting-4, sorting-6, stacking, inserting")]
pub struct UnknownTask(pub String);

impl FromStr for TaskId {
    type Err = UnknownTask;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let norm = s.trim().to_ascii_lowercase().replace('_', "-");
        TaskId::ALL
            .into_iter()
            .find(|t| t.slug() == norm)
            .ok_or_else(|| UnknownTask(s.to_string()))
    }
}

/// Observation modality of a policy.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ObsType {
    State,
    Image,
}

impl ObsType {
    pub fn as_str(self) -> &'static str {
        match self {
            ObsType::State => "state",
            ObsType::Image => "image",
        }
    }
}

impl FromStr for ObsType {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.trim().to_ascii_lowercase().as_str() {
            "state" => Ok(ObsType::State),
            "image" => Ok(ObsType::Image),
            other => Err(format!(
                "unknown observation type `{other}`; expected `state` or `image`"
            )),
        }
    }
}

impl fmt::Display for ObsType {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

/// How an image evaluation drew the robot (docs/images.md, "How close our
/// pixels are to the original's"). Physics is the same either way; only the
/// pixels an image policy sees differ, so image results drawn with different
/// looks are kept apart.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Default, Serialize, Deserialize,
)]
#[serde(rename_all = "lowercase")]
pub enum RobotLook {
    /// Capsules and boxes inside the original's mesh bounds (docs/mjcf.md):
    /// what a build without the converted Panda meshes draws.
    #[default]
    Primitives,
    /// The Panda's visual meshes, drawn like the original's: the links white
    /// at alpha 0.1, twice; the hand and fingers opaque grey.
    Meshes,
}

impl RobotLook {
    pub const ALL: [RobotLook; 2] = [RobotLook::Meshes, RobotLook::Primitives];

    pub fn as_str(self) -> &'static str {
        match self {
            RobotLook::Primitives => "primitives",
            RobotLook::Meshes => "meshes",
        }
    }
}

impl fmt::Display for RobotLook {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for RobotLook {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        RobotLook::ALL
            .into_iter()
            .find(|l| l.as_str() == s)
            .ok_or_else(|| format!("unknown robot look `{s}`; expected `meshes` or `primitives`"))
    }
}

/// What pages say about a result whose frames were not drawn as the
/// original draws them ([`robot_look_note`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct RobotLookNote {
    /// A few words, for a badge and the heading of the rows ranked together.
    pub badge: &'static str,
    /// The explanation: the badge's tooltip, the submission page's line.
    pub text: &'static str,
}

/// How an evaluated result's robot was drawn, when that is not as the
/// original draws it: None for state results (nothing is drawn) and for image
/// results drawn with the Panda meshes. Image results with another look, or
/// with none recorded, saw other pixels than the original's and are ranked
/// apart.
pub fn robot_look_note(obs: ObsType, look: Option<RobotLook>) -> Option<RobotLookNote> {
    match (obs, look) {
        (ObsType::State, _) | (ObsType::Image, Some(RobotLook::Meshes)) => None,
        (ObsType::Image, Some(RobotLook::Primitives)) => Some(RobotLookNote {
            badge: "primitive robot",
            text:
                "robot drawn with primitive shapes (capsules and boxes), not the Panda's meshes: \
                   the evaluating host had no converted meshes",
        }),
        (ObsType::Image, None) => Some(RobotLookNote {
            badge: "robot look not recorded",
            text: "robot look not recorded (evaluated before results recorded it)",
        }),
    }
}

/// Dimensions a policy must match for a task (docs/original-d3il.md §10, docs/original-d3il.md §11: the policy input
/// prepends the previous command to the environment observation).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TaskSpec {
    pub task: TaskId,
    /// Length of the policy-level observation vector (state part).
    pub obs_dim: usize,
    /// Length of one policy-level action (e.g. 2 xy deltas for Avoiding).
    pub act_dim: usize,
    /// Maximum env steps per episode.
    pub max_steps: usize,
    /// |B|.
    pub n_behaviours: usize,
}

/// Size and limits of a task's full ("paper") evaluation protocol.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PaperProtocol {
    /// Fixed initial states used.
    pub contexts: usize,
    /// Rollouts per initial state.
    pub rollouts: usize,
    /// Episode limit in env steps (state observations).
    pub max_steps: usize,
    /// Episode limit with image observations, if the task has that variant.
    pub max_steps_image: Option<usize>,
    /// True when the protocol is this project's own definition because the
    /// reference has no evaluation loop for the task (Inserting).
    pub ours: bool,
}

impl PaperProtocol {
    /// One line for pages: "60 initial states × 8 rollouts (480), at most 400 steps".
    pub fn describe(&self, obs: ObsType) -> String {
        let steps = match obs {
            ObsType::Image => self.max_steps_image.unwrap_or(self.max_steps),
            ObsType::State => self.max_steps,
        };
        let states = if self.contexts == 1 {
            "1 initial state".to_string()
        } else {
            format!("{} initial states", self.contexts)
        };
        format!(
            "{states} × {} rollouts ({} in all), at most {steps} steps per episode",
            self.rollouts,
            self.contexts * self.rollouts
        )
    }
}

/// Which evaluation protocol to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum ProtocolKind {
    /// The paper's protocol: all fixed initial states x rollouts per state.
    #[default]
    Paper,
    /// A small subset for smoke tests and dry runs (first few initial states, few rollouts).
    Quick,
}

impl ProtocolKind {
    /// The name serde, the CLI (`--protocol`) and the store use.
    pub fn as_str(self) -> &'static str {
        match self {
            ProtocolKind::Paper => "paper",
            ProtocolKind::Quick => "quick",
        }
    }
}

impl std::str::FromStr for ProtocolKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "paper" => Ok(ProtocolKind::Paper),
            "quick" => Ok(ProtocolKind::Quick),
            o => Err(format!(
                "unknown protocol `{o}`; expected `paper` or `quick`"
            )),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::RobotLook;

    #[test]
    fn robot_looks_parse_from_the_names_serde_writes() {
        for look in RobotLook::ALL {
            let json = serde_json::to_value(look).unwrap();
            assert_eq!(json, look.as_str());
            assert_eq!(look.as_str().parse::<RobotLook>(), Ok(look));
        }
        let e = "capsules".parse::<RobotLook>().unwrap_err();
        assert!(
            e.contains("`capsules`") && e.contains("`meshes` or `primitives`"),
            "{e}"
        );
    }
}
