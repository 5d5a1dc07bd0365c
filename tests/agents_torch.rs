//! The way in for trained reference agents (issue 39), run with real torch: the
//! pytest suite of clients/python/tests_torch in the torch virtualenv `./dev test`
//! makes (`$D3IL_TORCH_PYTHON`, default ~/.cache/d3il/venvs/torch/bin/python).
//! For every D3IL method family it builds an agent with the reference classes'
//! interface and quirks (tests_torch/reference_like), exports it with
//! `d3il_client.agents.export_agent` (checked against the agent's own `predict()`,
//! onnxruntime and this build's `d3il infer`), evaluates the file with this build's
//! `d3il eval --protocol quick`, and serves the agent to `d3il eval` over the remote
//! protocol with the actions compared to `predict()`.

use std::path::PathBuf;
use std::process::Command;

fn torch_python() -> PathBuf {
    if let Some(p) = std::env::var_os("D3IL_TORCH_PYTHON") {
        return PathBuf::from(p);
    }
    let home = std::env::var_os("HOME").expect("HOME is set");
    PathBuf::from(home).join(".cache/d3il/venvs/torch/bin/python")
}

#[test]
fn every_reference_agent_family_exports_checks_evaluates_and_serves() {
    let root = env!("CARGO_MANIFEST_DIR");
    let python = torch_python();
    assert!(
        python.exists(),
        "{} is missing: `./dev test` installs the torch virtualenv (clients/python/requirements-torch.txt)",
        python.display()
    );
    let out = Command::new(&python)
        .args([
            "-m",
            "pytest",
            "-q",
            "-p",
            "no:cacheprovider",
            // one pytest worker per core (pytest-xdist): each test's torch runs on
            // one thread (tests_torch/conftest.py), so the suite takes half the
            // wall time on CI's 2 cores
            "-n",
            "auto",
            "clients/python/tests_torch",
        ])
        .current_dir(root)
        .env(
            "PYTHONPATH",
            format!("{root}/clients/python:{root}/clients/python/tests_torch"),
        )
        .env("D3IL_BIN", env!("CARGO_BIN_EXE_d3il"))
        .output()
        .expect("run pytest in the torch virtualenv");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stdout}\n{stderr}");
    assert!(
        out.status.success(),
        "tests_torch failed:\n{stdout}\n{stderr}"
    );
    // pytest's summary line, e.g. "42 passed in 61.2s": nothing skipped.
    assert!(
        !stdout.contains(" skipped"),
        "a test of tests_torch skipped itself:\n{stdout}"
    );
}
