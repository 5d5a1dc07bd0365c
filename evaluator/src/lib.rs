//! Everything that runs a policy in the D3IL re-implementation.
//!
//! `unsafe` is denied everywhere in this crate except [`mujoco`], the binding
//! to MuJoCo's C API (and its renderer), which keeps every raw pointer behind
//! a safe interface.

#![deny(unsafe_code)]

pub mod camera;
#[cfg(feature = "engine")]
pub mod canary;
#[cfg(feature = "engine")]
pub mod demos;
#[cfg(feature = "engine")]
pub mod eval;
#[cfg(feature = "engine")]
pub mod fidelity;
#[cfg(feature = "engine")]
pub mod job;
#[allow(unsafe_code)]
pub mod mujoco;
pub mod open_loop;
pub mod perturb;
pub mod perturb_view;
pub mod replay_input;
pub mod robot;
#[cfg(feature = "engine")]
pub mod robustness;
#[cfg(feature = "engine")]
pub mod scripted;
#[cfg(feature = "engine")]
pub mod suite_shard;
#[cfg(feature = "engine")]
pub use d3il_metrics::shard;
pub mod sim;
pub mod tasks;
pub mod trace;
pub mod video;
