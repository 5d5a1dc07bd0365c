//! Benches do not rot: every `d3il bench` runs its `--smoke` mode through the
//! real binary and must end the way a full run ends (its ratio, or for
//! `scripts` its verdict line), so a bench broken by a later change fails
//! here instead of for the next person who runs it. The numbers of a smoke
//! run mean nothing and are not checked. The benches run one after another
//! (several measure latency or pin cores), about two minutes in all.
//!
//! Needs what the full benches need: ffmpeg (video), PostgreSQL and taskset
//! (scale, chaos), onnxruntime in python3 (agents), websockets and msgpack
//! in python3 (chaos's remote endpoint), the torch virtualenv (served-agent,
//! `$D3IL_TORCH_PYTHON`); `./dev test` installs them.

use std::process::Command;

fn d3il() -> Command {
    Command::new(env!("CARGO_BIN_EXE_d3il"))
}

#[test]
fn every_bench_names_itself_and_runs_its_smoke_mode_to_the_end() {
    // The benches are the binary's own list (`d3il bench`'s possible
    // values, src/bench/mod.rs `Bench`), so a bench added there runs here
    // without being named twice; an unknown name is refused with that list.
    let out = d3il().args(["bench", "no-such-bench"]).output().unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    let listed: Vec<String> = err
        .split("[possible values: ")
        .nth(1)
        .and_then(|rest| rest.split(']').next())
        .unwrap_or_else(|| panic!("no list of benches in: {err}"))
        .split(", ")
        .map(str::to_string)
        .collect();
    for expected in ["physics", "eval", "served-agent", "intervals"] {
        assert!(
            listed.iter().any(|b| b == expected),
            "{expected} missing from {listed:?}"
        );
    }

    let mut failed = Vec::new();
    for bench in &listed {
        let t = std::time::Instant::now();
        let out = d3il().args(["bench", bench, "--smoke"]).output().unwrap();
        let stdout = String::from_utf8_lossy(&out.stdout);
        let stderr = String::from_utf8_lossy(&out.stderr);
        let last = stdout.lines().last().unwrap_or("").to_string();
        eprintln!(
            "d3il bench {bench} --smoke: {:.1} s, last line {last:?}",
            t.elapsed().as_secs_f64()
        );
        let ends_right = if bench == "scripts" {
            last.contains("expectations not checked")
                && stdout.lines().filter(|l| l.contains(" expected ")).count() >= 10
        } else {
            last.contains("ratio")
        };
        if !out.status.success() || !ends_right {
            failed.push(format!(
                "d3il bench {bench} --smoke ({}):\n{stdout}\n{stderr}",
                out.status
            ));
        }
    }
    assert!(failed.is_empty(), "{}", failed.join("\n\n"));
}
