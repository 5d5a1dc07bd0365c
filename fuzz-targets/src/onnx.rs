//! ONNX admission: [`d3il_policy::onnx::admit`], what a worker runs on an
//! uploaded model (parse, checks against the manifest and the task, graph
//! analysis, the test inference at batch 2). In production it runs inside
//! the worker's sandbox; the afl binary confines each fuzzing process the
//! same way first ([`confine_like_worker`]; what still differs is listed in
//! docs/reliability.md, "Fuzzing").

use crate::assert_described;
use d3il_protocol::{Job, Limits, PolicyManifest, PolicySource, ProtocolKind, SandboxMechanism};

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

/// Confines the calling process as `d3il worker` confines itself for an
/// ONNX job ([`d3il_sandbox::confine`]: the worker's rlimits with the 4 GiB
/// address space, an empty network namespace, no capabilities, landlock
/// read-only to the assets, seccomp), with the default [`Limits`]. The
/// process must be single-threaded; afl's fork server calls it once in each
/// child, before the first run. Returns the mechanisms and whether each is
/// in force here.
pub fn confine_like_worker() -> Result<Vec<SandboxMechanism>, String> {
    let manifest: PolicyManifest =
        serde_json::from_str(MANIFESTS[0]).map_err(|e| format!("fixture manifest: {e}"))?;
    let job = Job {
        kind: d3il_protocol::JobKind::Plain,
        job_id: "fuzz".into(),
        task: manifest.task,
        protocol: ProtocolKind::Quick,
        policy: PolicySource::Onnx {
            path: "fuzz-input.onnx".into(),
            sha256: String::new(),
        },
        manifest,
        seed: 0,
        limits: Limits::default(),
        assets_dir: concat!(env!("CARGO_MANIFEST_DIR"), "/../assets").into(),
        dry_run_steps: None,
        build: None,
    };
    d3il_sandbox::confine(&job, &[]).map_err(|e| e.to_string())
}
