//! Everything that runs a policy in the D3IL re-implementation.

pub mod camera;
#[cfg(feature = "engine")]
pub mod eval;
pub mod mujoco;
pub mod robot;
#[cfg(feature = "engine")]
pub mod scripted;
pub mod sim;
pub mod tasks;
