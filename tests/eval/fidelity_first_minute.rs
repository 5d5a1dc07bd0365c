//! A fidelity page from the first minute (issue 43 item 3): with `--fidelity
//! full` on a build that has no report cached, the server computes the quick
//! report first and shows it, labelled, while the full one is computed; the
//! full one then replaces it; a restart of the same build shows the cached
//! full report at once.
//!
//! The quick report is the real `d3il fidelity --quick`. The full one takes
//! tens of minutes on two cores, so here `d3il fidelity` is called through a
//! wrapper whose full run waits for the test's go and then writes the quick
//! report relabelled `full`: what is tested is the order of the states and
//! the replacement, not the full report's numbers (tests/chromium/fidelity_chromium.rs
//! renders a real report; `d3il fidelity` itself makes the full one).

use d3il_protocol::fidelity::FidelityMode;
use d3il_server::fidelity::{FidelityConfig, FidelityReports, FidelityState, Next};
use d3il_test_support::TempDir;
use std::os::unix::fs::PermissionsExt;
use std::sync::Arc;
use std::time::{Duration, Instant};

fn wrapper(dir: &std::path::Path) -> std::path::PathBuf {
    let gate = dir.join("go");
    let script = format!(
        r#"#!/bin/sh
# d3il fidelity as the server calls it (--format json --exit-with-parent --out PATH [--quick]).
out=""; quick=""; prev=""
for a in "$@"; do
  [ "$prev" = --out ] && out="$a"
  [ "$a" = --quick ] && quick=1
  prev="$a"
done
[ -n "$quick" ] && exec '{real}' "$@"
while [ ! -e '{gate}' ]; do sleep 0.2; done
sed 's/"mode": *"quick"/"mode": "full"/' "$(dirname "$out")"/*-quick.json > "$out.part" && mv "$out.part" "$out"
"#,
        real = env!("CARGO_BIN_EXE_d3il"),
        gate = gate.display()
    );
    let path = dir.join("d3il-fidelity");
    std::fs::write(&path, script).unwrap();
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    path
}

fn reports(exe: &std::path::Path, dir: &std::path::Path) -> Arc<FidelityReports> {
    let mut cfg = FidelityConfig::new(exe.to_path_buf());
    cfg.mode = Some(FidelityMode::Full);
    cfg.nice = 0;
    cfg.dir = Some(dir.join("cache"));
    let r = Arc::new(FidelityReports::new(cfg, dir));
    r.start();
    r
}

/// Polls until `f` holds for the state (or panics with the last one).
fn wait(r: &FidelityReports, secs: u64, what: &str, f: impl Fn(&FidelityState) -> bool) {
    let end = Instant::now() + Duration::from_secs(secs);
    loop {
        let s = r.state();
        if f(&s) {
            return;
        }
        assert!(Instant::now() < end, "{what}: still {s:?} after {secs} s");
        std::thread::sleep(Duration::from_millis(200));
    }
}

fn shown(s: &FidelityState) -> Option<(FidelityMode, Next)> {
    match s {
        FidelityState::Ready { report, next } => Some((report.mode, next.clone())),
        _ => None,
    }
}

#[test]
fn the_quick_report_is_shown_until_the_full_one_replaces_it() {
    let rt = tokio::runtime::Runtime::new().unwrap();
    let _guard = rt.enter();
    let dir = TempDir::new("fidelity-first-minute");
    let exe = wrapper(dir.path());

    let r = reports(&exe, dir.path());
    assert!(
        matches!(
            r.state(),
            FidelityState::Computing { .. } | FidelityState::Ready { .. }
        ),
        "{:?}",
        r.state()
    );
    // Nothing cached: the quick report is computed first.
    wait(&r, 5, "the quick report first", |s| {
        matches!(
            s,
            FidelityState::Computing {
                mode: FidelityMode::Quick,
                ..
            }
        )
    });
    wait(&r, 600, "the quick report shown", |s| shown(s).is_some());
    let (mode, next) = shown(&r.state()).unwrap();
    assert_eq!(mode, FidelityMode::Quick);
    assert!(matches!(next, Next::Full { .. }), "{next:?}");
    let full: Vec<_> = std::fs::read_dir(dir.path().join("cache"))
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().ends_with("-full.json"))
        .collect();
    assert!(full.is_empty(), "no full report yet");
    // It stays while the full one is computed.
    std::thread::sleep(Duration::from_secs(1));
    assert_eq!(shown(&r.state()).unwrap().0, FidelityMode::Quick);

    std::fs::write(dir.path().join("go"), "").unwrap();
    wait(&r, 60, "the full report replaces the quick one", |s| {
        shown(s) == Some((FidelityMode::Full, Next::Nothing))
    });

    // The same build again: the cached full report at once, no quick step.
    let again = reports(&exe, dir.path());
    wait(&again, 10, "the cached full report", |s| {
        assert!(
            !matches!(
                s,
                FidelityState::Computing {
                    mode: FidelityMode::Quick,
                    ..
                }
            ),
            "a cached full report needs no quick one: {s:?}"
        );
        shown(s) == Some((FidelityMode::Full, Next::Nothing))
    });
}
