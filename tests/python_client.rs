//! The Python client's pytest suite (clients/python/tests) against the `d3il`
//! that cargo just built: real `d3il serve` processes on 127.0.0.1, real uploads
//! and quick-protocol evaluations, the README's "From Python" example and a
//! whole submission in a virtualenv holding only `pip install ./clients/python`,
//! every answer checked against the server's OpenAPI document, ruff and mypy.
//!
//! It runs as a cargo test, rather than as a step of ./dev after `cargo test`,
//! so that pytest gets this build's binary (CARGO_BIN_EXE_d3il, never a stale
//! target/debug/d3il), fails `cargo test` like any other test, and runs under
//! `.ci/run`'s `./dev test` with nothing added. ./dev makes the two virtualenvs
//! in target/python-client (`fresh`: the package only; `dev`: with pytest,
//! jsonschema, ruff, mypy).

use std::path::Path;
use std::process::Command;

#[test]
fn the_python_client_suite_passes_against_this_build() {
    let repo = Path::new(env!("CARGO_MANIFEST_DIR"));
    let venvs = repo.join("target/python-client");
    let python = venvs.join("dev/bin/python");
    let fresh = venvs.join("fresh/bin/python");
    for p in [&python, &fresh] {
        assert!(
            p.exists(),
            "{} is missing: run ./dev test, which makes the Python client's virtualenvs",
            p.display()
        );
    }
    let out = Command::new(&python)
        .args(["-m", "pytest", "-q", "-p", "no:cacheprovider", "tests"])
        .current_dir(repo.join("clients/python"))
        .env("D3IL_BIN", env!("CARGO_BIN_EXE_d3il"))
        .env("D3IL_FRESH_PYTHON", &fresh)
        .env_remove("PYTHONPATH")
        .output()
        .expect("run pytest");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "pytest failed ({}):\n{stdout}\n{stderr}",
        out.status
    );
    // Say what ran, so a suite that collected nothing does not pass unseen.
    let summary = stdout.lines().last().unwrap_or_default();
    assert!(summary.contains(" passed"), "pytest's summary: {summary}");
    assert!(
        !summary.contains("skipped"),
        "pytest skipped tests: {summary}"
    );
    println!("pytest: {summary}");
}
