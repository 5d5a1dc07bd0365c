//! d3il-sandbox: everything that keeps an untrusted submission from hurting the
//! host (docs/sandbox.md).
//!
//! Two sides:
//! - the **child** (`d3il worker`): [`confine`] applies rlimits, a fresh network
//!   namespace (file policies), landlock and a seccomp filter to its own process
//!   before anything from the submission is parsed; [`worker_main`] is the whole
//!   worker flow (read the job, confine, stream JSON lines, exit codes);
//! - the **parent** (server, `d3il eval --sandbox`): [`run_worker`] spawns the
//!   worker in its own process group, enforces the wall clock, caps the output and
//!   turns every way the worker can end into a typed [`Outcome`].
//!
//! Remote endpoints are checked by [`validate_endpoint`] (scheme, host, and no
//! loopback/link-local/private addresses unless the job allows them).

//!
//! `unsafe` is denied except in the modules that call libc directly, each for
//! a reason stated there: [`child`] (moving the protocol stream off fd 1), [`confine`]
//! (rlimits, namespaces, landlock and seccomp system calls), [`parent`]
//! (process groups, `waitid`/`wait4` with resource usage) and [`selftest`]
//! (deliberate misbehaviour for the hostile-worker tests).

#![deny(unsafe_code)]

#[allow(unsafe_code)]
pub mod child;
#[allow(unsafe_code)]
pub mod confine;
pub mod endpoint;
#[allow(unsafe_code)]
mod group;
#[allow(unsafe_code)]
pub mod parent;
#[allow(unsafe_code)]
pub mod selftest;

pub use child::{check_sandbox, check_sandbox_with, worker_main, WorkerOptions};
pub use confine::{confine, SandboxError};
pub use endpoint::{validate_endpoint, EndpointError};
pub use parent::{
    live_group_members, run_worker, run_worker_cancellable, run_worker_reporting, suite_limits,
    Outcome, WorkerCommand, WorkerRun, DEFAULT_MAX_OUTPUT_BYTES,
};
