//! The simulated robot in its scene: one `Data` plus the controller state,
//! with the substep, env-step physics and reset sequence of docs/original-d3il.md §01.4.

pub mod scene;

use crate::mujoco::{Data, MjError, Model, ObjKind};
use crate::robot::control::{self, CartesianTracker, FingerCommand};
use crate::robot::kinematics::PandaKinematics;
use crate::robot::Q_SCENE;
use std::sync::Arc;

/// Addresses of the robot's joints, actuators and TCP body in a compiled model.
#[derive(Debug, Clone)]
pub struct RobotIds {
    pub arm_qpos: [usize; 7],
    pub arm_dof: [usize; 7],
    pub finger_qpos: [usize; 2],
    pub finger_dof: [usize; 2],
    /// Actuator indices: joint1..7, finger1, finger2.
    pub actuators: [usize; 9],
    pub tcp_body: usize,
}

impl RobotIds {
    pub fn lookup(m: &Model) -> Result<RobotIds, MjError> {
        let mut arm_qpos = [0; 7];
        let mut arm_dof = [0; 7];
        let mut actuators = [0; 9];
        for i in 0..7 {
            let j = format!("panda_rb0_joint{}", i + 1);
            arm_qpos[i] = m.joint_qpos_addr(&j)?;
            arm_dof[i] = m.joint_dof_addr(&j)?;
            actuators[i] = m.id(ObjKind::Actuator, &format!("{j}_act"))?;
        }
        let mut finger_qpos = [0; 2];
        let mut finger_dof = [0; 2];
        for i in 0..2 {
            let j = format!("panda_rb0_finger_joint{}", i + 1);
            finger_qpos[i] = m.joint_qpos_addr(&j)?;
            finger_dof[i] = m.joint_dof_addr(&j)?;
            actuators[7 + i] = m.id(ObjKind::Actuator, &format!("{j}_act"))?;
        }
        Ok(RobotIds {
            arm_qpos,
            arm_dof,
            finger_qpos,
            finger_dof,
            actuators,
            tcp_body: m.id(ObjKind::Body, "tcp_rb0")?,
        })
    }
}

/// The controller that drives the arm at every substep.
#[derive(Debug, Clone)]
pub enum ArmController {
    /// Joint PD to a fixed configuration with zero velocity reference (reset hold).
    Hold([f64; 7]),
    /// Cartesian IK tracking (rod tasks, docs/original-d3il.md §01.3.4).
    Cartesian(CartesianTracker),
    /// Joint-space PD to float32-rounded targets (Stacking, docs/original-d3il.md §01.3.6).
    Joint([f64; 7]),
}

/// A robot in a scene, with its controller state.
pub struct Sim {
    pub data: Data,
    pub ids: Arc<RobotIds>,
    kin: PandaKinematics,
    pub arm: ArmController,
    pub fingers: FingerCommand,
    pub n_substeps: usize,
    /// When set, the controls of every substep are appended here (benchmarks).
    pub ctrl_recorder: Option<Vec<[f64; 9]>>,
}

fn pick<const N: usize>(v: &[f64], idx: &[usize; N]) -> [f64; N] {
    idx.map(|i| v[i])
}

impl Sim {
    pub fn new(model: Arc<Model>, ids: Arc<RobotIds>, n_substeps: usize) -> Result<Sim, MjError> {
        Ok(Sim {
            data: Data::new(model)?,
            ids,
            kin: PandaKinematics::new(),
            arm: ArmController::Hold(Q_SCENE),
            fingers: FingerCommand::RESET,
            n_substeps,
            ctrl_recorder: None,
        })
    }

    /// Fresh arm joint positions (docs/original-d3il.md §01.4.3).
    pub fn joint_pos(&self) -> [f64; 7] {
        pick(self.data.qpos(), &self.ids.arm_qpos)
    }
    pub fn joint_vel(&self) -> [f64; 7] {
        pick(self.data.qvel(), &self.ids.arm_dof)
    }
    pub fn finger_pos(&self) -> [f64; 2] {
        pick(self.data.qpos(), &self.ids.finger_qpos)
    }
    pub fn finger_vel(&self) -> [f64; 2] {
        pick(self.data.qvel(), &self.ids.finger_dof)
    }
    pub fn gripper_width(&self) -> f64 {
        let f = self.finger_pos();
        f[0] + f[1]
    }
    /// `data.xpos` of `tcp_rb0`: one substep stale after `mj_step` (docs/original-d3il.md §01.4.3).
    pub fn tcp_pos(&self) -> [f64; 3] {
        self.data.xpos(self.ids.tcp_body)
    }

    /// `data.xquat` of `tcp_rb0` (w, x, y, z), as stale as [`Sim::tcp_pos`].
    pub fn tcp_quat(&self) -> [f64; 4] {
        self.data.xquat(self.ids.tcp_body)
    }

    /// Controller -> ctrl, then one `mj_step` (docs/original-d3il.md §01.4.1).
    pub fn substep(&mut self) -> Result<(), MjError> {
        let q = self.joint_pos();
        let qdot = self.joint_vel();
        let tau_pd = match &mut self.arm {
            ArmController::Hold(q_d) => control::joint_pd(q_d, &[0.0; 7], &q, &qdot),
            ArmController::Joint(q_cmd) => control::joint_pd(q_cmd, &[0.0; 7], &q, &qdot),
            ArmController::Cartesian(t) => {
                let (q_d, qdot_d) = t.desired(&self.kin, &q);
                control::joint_pd(&q_d, &qdot_d, &q, &qdot)
            }
        };
        // Bias as left by the previous mj_step: one substep stale (docs/original-d3il.md §01.3.5).
        let bias = pick(self.data.qfrc_bias(), &self.ids.arm_dof);
        let f = control::finger_forces(self.fingers, self.finger_pos(), self.finger_vel());
        let act = self.ids.actuators;
        let ctrl = self.data.ctrl_mut();
        for i in 0..7 {
            ctrl[act[i]] = tau_pd[i] + bias[i];
        }
        ctrl[act[7]] = f[0];
        ctrl[act[8]] = f[1];
        if let Some(rec) = &mut self.ctrl_recorder {
            let c = self.data.ctrl();
            rec.push(act.map(|i| c[i]));
        }
        self.data.step()
    }

    /// The physics of one env step: `n_substeps` substeps (docs/original-d3il.md §01.4.2 step 4).
    pub fn step_physics(&mut self) -> Result<(), MjError> {
        for _ in 0..self.n_substeps {
            self.substep()?;
        }
        Ok(())
    }

    /// Reset sequence of docs/original-d3il.md §01.4.4. `place_objects` writes free-joint qpos
    /// (no forward); `fingers` is the finger command of the single hold substep
    /// (0.001 for rod tasks, open for Stacking).
    pub fn reset(
        &mut self,
        init_qpos: &[f64; 7],
        fingers: FingerCommand,
        place_objects: impl FnOnce(&mut Data),
    ) -> Result<(), MjError> {
        self.fingers = FingerCommand::RESET;
        self.data.reset();
        {
            let ids = self.ids.clone();
            let qpos = self.data.qpos_mut();
            for i in 0..7 {
                qpos[ids.arm_qpos[i]] = Q_SCENE[i];
            }
            for i in 0..2 {
                qpos[ids.finger_qpos[i]] = 0.0;
            }
            self.data.qvel_mut().fill(0.0);
        }
        self.data.forward()?;
        self.data.forward()?;
        {
            let ids = self.ids.clone();
            let qpos = self.data.qpos_mut();
            for i in 0..7 {
                qpos[ids.arm_qpos[i]] = init_qpos[i];
            }
            let qvel = self.data.qvel_mut();
            for i in 0..7 {
                qvel[ids.arm_dof[i]] = 0.0;
            }
        }
        self.data.forward()?;
        self.arm = ArmController::Hold(*init_qpos);
        place_objects(&mut self.data);
        self.fingers = fingers;
        self.substep()
    }

    /// Switch to Cartesian tracking toward (pos, quat), keeping the IK state
    /// across steps of the same episode.
    pub fn set_cartesian_target(&mut self, pos: [f64; 3], quat: [f64; 4]) {
        if !matches!(self.arm, ArmController::Cartesian(_)) {
            self.arm = ArmController::Cartesian(CartesianTracker::new());
        }
        if let ArmController::Cartesian(t) = &mut self.arm {
            t.set_target(pos, quat);
        }
    }
}

#[cfg(test)]
mod tests;
