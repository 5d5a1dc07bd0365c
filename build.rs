//! Records the git commit the `d3il` binary is built from (the build identity
//! of every result's manifest, CHANGELOG.md). Outside a git checkout: `unknown`.

use std::process::Command;

fn main() {
    for watched in [".git/HEAD", ".git/refs/heads", ".git/packed-refs"] {
        println!("cargo:rerun-if-changed={watched}");
    }
    let commit = Command::new("git")
        .args(["rev-parse", "HEAD"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
        .filter(|s| s.len() == 40)
        .unwrap_or_else(|| "unknown".into());
    println!("cargo:rustc-env=D3IL_GIT_COMMIT={commit}");
}
