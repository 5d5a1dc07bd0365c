//! Everything that runs a policy in the D3IL re-implementation.

pub mod mujoco;
pub mod robot;
pub mod sim;
pub mod tasks;
