pub mod mujoco;
