//! The evaluator's integration tests, one test binary (each binary links the
//! whole stack, so a few large ones build much faster than one per file): every
//! task in real MuJoCo (resets, rollouts traced twice, scripted experts, the
//! reference values), rendering and screens, the Panda meshes, context sets and
//! behaviour names. One module per former test file. The display-counting
//! test stays a binary of its own (tests/render_screens.rs): other tests'
//! renderers in the same process would hold displays it counts.

mod common;

mod aligning;
mod avoiding;
mod behaviour_names;
mod context_sets;
mod inserting;
mod panda_meshes;
mod pushing;
mod reference_avoiding;
mod render;
mod sorting;
mod stacking;
