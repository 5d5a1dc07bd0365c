//! The `d3il` command line: output formats, verify, intervals, images,
//! replay, render goldens, reference frames, comparable numbers, fail-fast
//! errors and the zoo. One test binary; one module per former test file.

mod cli_output;
mod comparable_numbers;
mod fail_fast;
mod image_cli;
mod image_skip;
mod intervals_cli;
mod reference_frames;
mod render_golden;
mod replay_cli;
mod resnet_fixture;
mod verify;
mod zoo_cli;
