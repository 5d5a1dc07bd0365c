//! Evaluations end to end: agents served over websockets, local endpoints,
//! history windows, the fidelity view's first minute, identical rollouts and
//! remote and robustness evaluations in the container image. One test binary;
//! one module per former test file.

mod agent_server;
mod eval_local_endpoint;
mod eval_window;
mod fidelity_first_minute;
mod identical_rollouts;
mod remote_image;
mod robustness_image;
