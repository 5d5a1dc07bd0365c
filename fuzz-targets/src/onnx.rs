//! ONNX admission: [`d3il_policy::onnx::admit`], what a worker runs on an
//! uploaded model (parse, checks against the manifest and the task, graph
//! analysis, the test inference at batch 2). In production it runs inside
//! the worker's sandbox; [`apply_worker_limits`] gives the fuzzing process
//! the same address-space limit (the other confinements are listed in
//! docs/reliability.md).

use crate::assert_described;
use d3il_protocol::{Limits, PolicyManifest};

/// Manifests of the committed fixtures: the first byte of an input picks one.
const MANIFESTS: &[&str] = &[
    include_str!("../../assets/fixtures/aligning_mlp.json"),
    include_str!("../../assets/fixtures/avoiding_k5_h3.json"),
    include_str!("../../assets/fixtures/avoiding_noise.json"),
    include_str!("../../assets/fixtures/aligning_image.json"),
    include_str!("../../assets/fixtures/aligning_image_k2_h4.json"),
    include_str!("../../assets/fixtures/avoiding_path.json"),
];

pub fn onnx_admit(data: &[u8]) {
    let Some((&pick, model)) = data.split_first() else {
        return;
    };
    let text = MANIFESTS[usize::from(pick) % MANIFESTS.len()];
    let manifest: PolicyManifest = serde_json::from_str(text).expect("fixture manifests parse");
    let def = d3il_evaluator::tasks::task_def(manifest.task).expect("fixture tasks exist");
    let spec = def.spec_for(manifest.obs_type);
    if let Err(e) = d3il_policy::onnx::admit(model, &manifest, &spec, 0) {
        assert_described("onnx admission", &e);
    }
}

/// The worker's address-space limit ([`Limits::memory_bytes`], applied by
/// `d3il_sandbox` with `setrlimit(RLIMIT_AS)`), for the fuzzing process.
pub fn apply_worker_limits() -> std::io::Result<()> {
    let bytes = Limits::default().memory_bytes as libc::rlim_t;
    let lim = libc::rlimit {
        rlim_cur: bytes,
        rlim_max: bytes,
    };
    // SAFETY: a plain syscall with a pointer to a local struct.
    if unsafe { libc::setrlimit(libc::RLIMIT_AS, &lim) } != 0 {
        return Err(std::io::Error::last_os_error());
    }
    Ok(())
}
