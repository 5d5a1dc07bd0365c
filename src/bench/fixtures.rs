//! The ONNX fixtures of `assets/fixtures/` loaded as policies, for the
//! benches (`d3il bench eval`, `render`, `video`).

use anyhow::Context;
use d3il_evaluator::eval::{self, PolicyInfo};
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::OnnxPolicy;
use d3il_protocol::{ObsType, PolicyManifest};

/// `assets/fixtures/<name>.onnx` with its manifest `<name>.json`, for `task`.
pub(super) fn load_fixture(
    task: &LoadedTask,
    name: &str,
    obs_type: ObsType,
) -> anyhow::Result<(OnnxPolicy, PolicyInfo)> {
    let dir = crate::common::assets_dir().join("fixtures");
    let onnx = dir.join(format!("{name}.onnx"));
    let bytes = std::fs::read(&onnx).with_context(|| format!("reading {}", onnx.display()))?;
    let manifest: PolicyManifest =
        serde_json::from_slice(&std::fs::read(dir.join(format!("{name}.json")))?)?;
    let policy = OnnxPolicy::load(&bytes, &manifest, &task.spec(), 0)?;
    let info = PolicyInfo {
        sha256: eval::sha256_hex(&bytes),
        obs_type,
    };
    Ok((policy, info))
}
