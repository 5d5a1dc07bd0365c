//! Every committed fuzz input runs through its harness without a finding:
//! the seeds (fuzz/seeds), the corpora the fuzzer grew and afl-cmin
//! minimised (fuzz/corpus), and every crash it found
//! (fuzz/regressions/<target>/, each fixed in the parser). A harness
//! panics on a finding, so a regression fails here by name.

use std::path::{Path, PathBuf};

fn fuzz_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz")
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.is_file()
                && !p
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with('.'))
        })
        .collect();
    v.sort();
    v
}

fn run_all(kind: &str, target: &d3il_fuzz_targets::Target) -> usize {
    let inputs = files(&fuzz_dir().join(kind).join(target.name));
    for path in &inputs {
        let data = std::fs::read(path).expect("a committed input reads");
        let outcome = std::panic::catch_unwind(|| (target.run)(&data));
        assert!(
            outcome.is_ok(),
            "{} fails on {}",
            target.name,
            path.display()
        );
    }
    inputs.len()
}

/// Production catches tract's panics on malformed models (`OnnxPolicy::load`);
/// their messages would bury a real failure, so panics inside dependencies
/// are not printed (a harness's own assertion still is).
fn quiet_dependency_panics() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let in_dependency = info
            .location()
            .is_some_and(|l| l.file().contains("/.cargo/registry/"));
        if !in_dependency {
            default(info);
        }
    }));
}

#[test]
fn every_corpus_file_and_regression_runs_clean() {
    quiet_dependency_panics();
    for target in d3il_fuzz_targets::TARGETS {
        let seeds = run_all("seeds", target);
        let corpus = run_all("corpus", target);
        let regressions = run_all("regressions", target);
        eprintln!(
            "{}: {seeds} seeds, {corpus} corpus files, {regressions} regressions",
            target.name
        );
        assert!(
            seeds + corpus > 0,
            "{} has no committed inputs",
            target.name
        );
    }
}

/// Valid input is not a finding (a harness that flagged everything would
/// be as useless as one that checked nothing; lib.rs tests the latter).
#[test]
fn valid_inputs_are_not_findings() {
    let finds = |name: &str, data: &[u8]| {
        let t = d3il_fuzz_targets::target(name).expect("target");
        std::panic::catch_unwind(|| (t.run)(data)).is_err()
    };
    // A well-formed, valid input is not a finding.
    assert!(!finds(
        "manifest",
        br#"{"task": "avoiding", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#
    ));
    assert!(!finds("api_query", b"\x00aligning?obs=image"));
    assert!(!finds("remote_frame", b"\x03"));
}
