//! Records the git commit the `d3il` binary is built from (the build identity
//! of every result's manifest, CHANGELOG.md). Outside a git checkout: `unknown`.

use std::process::Command;

fn main() {
    // Cargo reruns a build script on every build when a watched path does not
    // exist, which relinks the binary each time (a checkout without
    // `.git/packed-refs`, or no `.git` at all): watch only what is there. A
    // commit always touches HEAD or the branch's file under refs/heads; packing
    // refs removes files from refs/heads, which is watched too.
    println!("cargo:rerun-if-changed=build.rs");
    for watched in [".git/HEAD", ".git/refs/heads", ".git/packed-refs"] {
        if std::path::Path::new(watched).exists() {
            println!("cargo:rerun-if-changed={watched}");
        }
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
