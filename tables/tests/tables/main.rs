//! The tables crate's tests, one test binary: the paper's tables in every format
//! (golden files, LaTeX round trip, evaluated rows, determinism), the figures'
//! SVG geometry (plots, clipped paths, the race figure, rollout pictures). One
//! module per former test file.

#[allow(dead_code)] // the rollout pictures' traces; clipped_paths uses a part
mod support;
#[path = "../svg_geometry/mod.rs"]
mod svg_geometry;

mod clipped_paths;
mod determinism;
mod evaluated;
mod figures;
mod golden;
mod latex_roundtrip;
mod plot_geometry;
mod race_figure;
mod rollout_pictures;
