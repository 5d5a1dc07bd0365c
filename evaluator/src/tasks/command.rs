//! How a policy action becomes the controller's command: the three command
//! conventions of the tasks, each stated once. [`TaskDef::command_kind`]
//! names a task's convention; the trait's `cmd_dim`, `act_dim`, `act_meaning`,
//! `initial_command` and `command` follow from it.
//!
//! [`TaskDef::command_kind`]: super::TaskDef::command_kind

use super::{Command, QUAT_DOWN};
use crate::sim::Sim;

/// A task's command convention.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CommandKind {
    /// Avoiding, Pushing, Sorting, Inserting (docs/original-d3il.md §10.1.7, docs/original-d3il.md §11.1.4,
    /// docs/original-d3il.md §11.3.4): previous desired TCP xy + float32 delta, z frozen at the
    /// post-reset TCP z, hand pointing down. The "previous command" starts at
    /// the measured TCP xy.
    XyDelta,
    /// Aligning (docs/original-d3il.md §10.3.4): previous desired TCP xyz + float32 delta, hand
    /// down, no fixed z; starts at the measured TCP xyz.
    XyzDelta,
    /// Stacking (docs/original-d3il.md §11.2.3, §11.2.4): q_d = previous q + Δq in float32 for the
    /// 7 joints, and an absolute gripper width (> 0.075 opens) that becomes
    /// index 7 of the next "previous command" (the prediction, not the
    /// measured width); starts at the measured joints and width as float32.
    JointDelta,
}

impl CommandKind {
    /// Width of one action, and of the "previous command" prefix of the
    /// policy input (the same for every convention).
    pub fn dim(self) -> usize {
        match self {
            CommandKind::XyDelta => 2,
            CommandKind::XyzDelta => 3,
            CommandKind::JointDelta => 8,
        }
    }

    /// How many leading entries of an action are increments; the rest
    /// (Stacking's gripper width) are absolute values, which scaling or
    /// adding noise would turn into another command (0.08 × 0.9 closes).
    pub fn increments(self) -> usize {
        match self {
            CommandKind::JointDelta => 7,
            k => k.dim(),
        }
    }

    /// What an action means, for error messages.
    pub fn meaning(self) -> &'static str {
        match self {
            CommandKind::XyDelta => "the xy delta of the desired TCP position",
            CommandKind::XyzDelta => "the xyz delta of the desired TCP position",
            CommandKind::JointDelta => {
                "7 joint-position increments (rad per step) and the absolute gripper width (> 0.075 opens)"
            }
        }
    }

    /// The action that leaves the controller where it is: what the robustness
    /// track's `latency` applies while the first late actions are in flight
    /// (`crate::perturb`). A zero delta in every convention; Stacking's
    /// absolute gripper value is "open", as the reset left the fingers
    /// (docs/original-d3il.md §11.0.5), not the measured width the first
    /// "previous command" holds (which, applied, would close them).
    pub fn hold(self) -> Vec<f32> {
        let mut hold = vec![0.0; self.dim()];
        if self == CommandKind::JointDelta {
            hold[7] = super::stacking::OPEN;
        }
        hold
    }

    /// What the environment receives under a fractional latency `L = n +
    /// f` (0 < f < 1, the robustness track's `latency`, `crate::perturb`):
    /// `newer` is the action issued `n` steps ago, `older` the one issued
    /// `n + 1` steps ago (either is [`CommandKind::hold`] while it has not
    /// arrived). Deltas are blended, `(1 − f)·newer + f·older`: over a run
    /// the blended increments add up to the issued ones, only later, so the
    /// command arrives on average `L` steps late. Stacking's gripper is an
    /// absolute width (open above 0.075), and a blend of an open and a
    /// closed command is a half-closed width no policy asked for: it is
    /// taken whole from the action with the larger share, the older one on
    /// a tie (f = 0.5). So the gripper is late by `L` rounded to the
    /// nearest step, half up: never earlier than the arm's blended command
    /// says, and with a whole-step latency the gripper and the arm stay in
    /// step as before.
    pub fn blend_late(self, newer: &[f32], older: &[f32], f: f32) -> Vec<f32> {
        let mut action: Vec<f32> = newer
            .iter()
            .zip(older)
            .map(|(&a, &b)| (1.0 - f) * a + f * b)
            .collect();
        if self == CommandKind::JointDelta {
            action[7] = if f < 0.5 { newer[7] } else { older[7] };
        }
        action
    }

    /// The first "previous command" after reset.
    pub fn initial(self, sim: &Sim) -> Vec<f64> {
        match self {
            CommandKind::XyDelta => {
                let p = sim.tcp_pos();
                vec![p[0], p[1]]
            }
            CommandKind::XyzDelta => sim.tcp_pos().to_vec(),
            CommandKind::JointDelta => {
                let mut v: Vec<f64> = sim.joint_pos().iter().map(|&q| q as f32 as f64).collect();
                v.push(sim.gripper_width() as f32 as f64);
                v
            }
        }
    }

    /// Previous command + policy action -> (new previous command, controller
    /// command). The delta is float32 and added to the float64 previous
    /// command (docs/original-d3il.md §01.7.12) in the Cartesian conventions.
    pub fn apply(self, prev: &[f64], action: &[f32], fixed_z: f64) -> (Vec<f64>, Command) {
        match self {
            CommandKind::XyDelta => {
                let x = prev[0] + action[0] as f64;
                let y = prev[1] + action[1] as f64;
                (
                    vec![x, y],
                    Command::Cartesian {
                        pos: [x, y, fixed_z],
                        quat: QUAT_DOWN,
                    },
                )
            }
            CommandKind::XyzDelta => {
                let p: [f64; 3] = std::array::from_fn(|i| prev[i] + action[i] as f64);
                (
                    p.to_vec(),
                    Command::Cartesian {
                        pos: p,
                        quat: QUAT_DOWN,
                    },
                )
            }
            CommandKind::JointDelta => {
                let q: [f64; 7] = std::array::from_fn(|i| (prev[i] as f32 + action[i]) as f64);
                let gripper = action[7] as f64;
                let mut next = q.to_vec();
                next.push(gripper);
                (next, Command::Joint { q, gripper })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xy_delta_keeps_z_and_points_down() {
        let (next, cmd) = CommandKind::XyDelta.apply(&[0.5, -0.2], &[0.01, -0.02], 0.12);
        assert_eq!(next, vec![0.5 + 0.01f32 as f64, -0.2 - 0.02f32 as f64]);
        assert_eq!(
            cmd,
            Command::Cartesian {
                pos: [next[0], next[1], 0.12],
                quat: QUAT_DOWN
            }
        );
    }

    #[test]
    fn xyz_delta_ignores_the_fixed_z() {
        let (next, cmd) = CommandKind::XyzDelta.apply(&[0.5, 0.0, 0.2], &[0.0, 0.0, -0.01], 9.0);
        assert_eq!(next[2], 0.2 - 0.01f32 as f64);
        assert!(matches!(cmd, Command::Cartesian { pos, .. } if pos[2] == next[2]));
    }

    #[test]
    fn joint_delta_adds_in_float32_and_keeps_the_gripper_absolute() {
        let prev = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.04];
        let act = [0.01f32, 0.0, 0.0, 0.0, 0.0, 0.0, -0.01, 0.08];
        let (next, cmd) = CommandKind::JointDelta.apply(&prev, &act, 0.0);
        assert_eq!(next[0], (0.1f32 + 0.01f32) as f64);
        assert_eq!(next[7], 0.08f32 as f64);
        assert!(matches!(cmd, Command::Joint { gripper, .. } if gripper == 0.08f32 as f64));
    }

    #[test]
    fn the_hold_action_keeps_the_command_and_an_open_gripper_open() {
        let prev = [0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.0002];
        let (next, cmd) =
            CommandKind::JointDelta.apply(&prev, &CommandKind::JointDelta.hold(), 0.0);
        assert_eq!(next[..7], prev.map(|v| v as f32 as f64)[..7]);
        assert!(matches!(cmd, Command::Joint { gripper, .. } if gripper > 0.075));
        for k in [CommandKind::XyDelta, CommandKind::XyzDelta] {
            assert_eq!(k.hold(), vec![0.0; k.dim()], "{k:?}");
        }
    }

    /// A fractional latency on Stacking: the joint increments are the
    /// blend, the gripper value whole from the action of the larger share
    /// (the older on a tie), the hold action's open gripper before the
    /// older action has arrived. The Cartesian conventions blend every entry.
    #[test]
    fn a_late_blend_mixes_the_joint_increments_and_takes_the_gripper_whole() {
        let k = CommandKind::JointDelta;
        let newer = [0.04f32, -0.02, 0.0, 0.01, 0.0, 0.0, 0.03, 0.0];
        let older = [0.0f32, 0.02, 0.01, 0.0, 0.0, -0.04, 0.0, 0.08];
        for (f, gripper) in [(0.25f32, 0.0), (0.5, 0.08), (0.75, 0.08)] {
            let a = k.blend_late(&newer, &older, f);
            let blend: Vec<f32> = newer
                .iter()
                .zip(&older)
                .map(|(n, o)| (1.0 - f) * n + f * o)
                .collect();
            assert_eq!(a[..7], blend[..7], "f {f}: the joint increments");
            assert_eq!(a[7], gripper, "f {f}: the gripper of the larger share");
        }
        // Nothing older has arrived yet: the hold action's zero deltas and
        // open gripper (the reset's), where the newer action closes it.
        let a = k.blend_late(&newer, &k.hold(), 0.5);
        assert_eq!(
            a[..7],
            newer[..7].iter().map(|v| 0.5 * v).collect::<Vec<_>>()[..]
        );
        assert!(a[7] > 0.075, "the hold action's gripper is open: {}", a[7]);
        let a = k.blend_late(&newer, &k.hold(), 0.25);
        assert_eq!(a[7], 0.0, "the newer action has the larger share");
        for k in [CommandKind::XyDelta, CommandKind::XyzDelta] {
            let (newer, older) = (vec![0.01f32; k.dim()], vec![-0.03f32; k.dim()]);
            let a = k.blend_late(&newer, &older, 0.25);
            assert_eq!(a, vec![0.75 * 0.01f32 + 0.25 * -0.03f32; k.dim()], "{k:?}");
        }
    }

    #[test]
    fn every_convention_has_action_width_equal_to_its_command_width() {
        for k in [
            CommandKind::XyDelta,
            CommandKind::XyzDelta,
            CommandKind::JointDelta,
        ] {
            let prev = vec![0.0; k.dim()];
            let act = vec![0.0f32; k.dim()];
            assert_eq!(k.apply(&prev, &act, 0.0).0.len(), k.dim(), "{k:?}");
        }
    }
}
