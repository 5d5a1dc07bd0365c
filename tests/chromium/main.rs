//! Headless Chromium (d3il_test_support::chromium) on the pages of the real
//! `d3il serve`: the board, plots, races, robustness, rollouts, the zoo and the
//! fidelity view. One test binary; one module per former test file.

/// The `d3il` binary under test (the server harness starts it, the tests run its other commands).
pub const D3IL: d3il_test_support::server::Binary =
    d3il_test_support::server::Binary(env!("CARGO_BIN_EXE_d3il"));
pub const EXE: &str = D3IL.0;

#[path = "../robustness_support/mod.rs"]
mod robustness_support;
#[path = "../rollouts_support/mod.rs"]
mod rollouts_support;

mod fidelity_chromium;
mod plots_chromium;
mod race_chromium;
mod robustness_chromium;
mod rollouts_chromium;
mod server_chromium;
mod zoo_chromium;
