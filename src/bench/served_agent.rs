//! `d3il bench served-agent`: a served BESO-sized reference agent
//! against the Aligning paper protocol. It runs clients/python/bench_served_agent.py,
//! which serves the reference's Aligning BESO in size and settings (random weights)
//! batched over the remote protocol on 127.0.0.1, times requests of the evaluator's
//! batch, compares them with the per-rollout `predict()` fallback and ends with the
//! ratio of the projected paper-protocol inference time to the default wall limit.
//!
//! The script needs torch: it runs in the torch virtualenv `./dev bench served-agent`
//! makes, `$D3IL_TORCH_PYTHON` when set, else `~/.cache/d3il/venvs/torch/bin/python`
//! (the same rule as tests/agents_torch.rs).

use anyhow::{bail, Context};
use std::path::PathBuf;
use std::process::Command;

/// The torch virtualenv's python: `$D3IL_TORCH_PYTHON`, else the default place.
fn torch_python() -> PathBuf {
    if let Some(p) = std::env::var_os("D3IL_TORCH_PYTHON").filter(|p| !p.is_empty()) {
        return PathBuf::from(p);
    }
    let home = std::env::var_os("HOME").unwrap_or_default();
    PathBuf::from(home).join(".cache/d3il/venvs/torch/bin/python")
}

/// Runs the script with its output passed through (its last line is the ratio).
pub fn run(smoke: bool, max_live: usize) -> anyhow::Result<()> {
    let python = torch_python();
    if !python.exists() {
        bail!(
            "{} is missing: this bench needs torch; `./dev bench served-agent` installs the torch virtualenv \
             (clients/python/requirements-torch.txt), or set D3IL_TORCH_PYTHON to a python with torch",
            python.display()
        );
    }
    let script = crate::common::assets_dir()
        .join("..")
        .join("clients")
        .join("python")
        .join("bench_served_agent.py");
    let mut cmd = Command::new(&python);
    cmd.arg(&script).arg("--max-live").arg(max_live.to_string());
    if smoke {
        cmd.arg("--smoke");
    }
    let status = cmd
        .status()
        .with_context(|| format!("running {} {}", python.display(), script.display()))?;
    if !status.success() {
        bail!("{} stopped ({status})", script.display());
    }
    Ok(())
}
