//! Issue 50: the zoo in the `d3il` command. `d3il tables --table zoo` loads
//! the zoo into the database (as `d3il serve` does at start) and prints its
//! own table in every format, never one of the paper's; `d3il zoo check`
//! reads every cell against its provenance; `d3il zoo reeval` evaluates every
//! cell again with this build and writes the version-drift table.
//! The fixture cell is server/tests/fixtures/zoo/avoiding/bc-mlp-s0.

use d3il_test_support::succeeded;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const EXE: &str = env!("CARGO_BIN_EXE_d3il");
const CELL: &str = "avoiding/bc-mlp-s0";

fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("server/tests/fixtures/zoo")
}

fn scratch(name: &str) -> PathBuf {
    let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("zoo-cli-{name}"));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn d3il(args: &[&str]) -> Output {
    Command::new(EXE)
        .args(args)
        .env("RUST_BACKTRACE", "0")
        .output()
        .expect("run d3il")
}

#[test]
fn tables_prints_the_zoo_in_a_table_of_its_own() {
    let dir = scratch("tables");
    let db = dir.join("lb.sqlite");
    let (db, zoo) = (db.to_str().unwrap(), fixture());
    let zoo = zoo.to_str().unwrap();
    let md = succeeded(
        &d3il(&[
            "tables", "--table", "zoo", "--format", "markdown", "--db", db, "--zoo", zoo,
        ]),
        "d3il tables",
    );
    assert!(
        md.contains("D3IL zoo: trained here on d3il demos v1"),
        "{md}"
    );
    assert!(md.contains("| Avoiding (T1) | BC-MLP |"), "{md}");
    // Twice: loaded once, the same table.
    let again = succeeded(
        &d3il(&[
            "tables", "--table", "zoo", "--format", "markdown", "--db", db, "--zoo", zoo,
        ]),
        "d3il tables",
    );
    assert_eq!(md, again);
    let csv = succeeded(
        &d3il(&[
            "tables", "--table", "zoo", "--format", "csv", "--db", db, "--zoo", zoo,
        ]),
        "d3il tables",
    );
    assert_eq!(csv.lines().count(), 2, "{csv}");
    assert!(csv.contains("trained here on d3il demos v1,Avoiding (T1),BC-MLP,paper"));
    let tex = succeeded(
        &d3il(&[
            "tables", "--table", "zoo", "--format", "latex", "--db", db, "--zoo", zoo,
        ]),
        "d3il tables",
    );
    assert!(tex.contains("\\caption{D3IL zoo: trained here on d3il demos v1."));

    // The paper's main table is the paper's alone: no zoo row in it.
    let main = succeeded(
        &d3il(&["tables", "--table", "main", "--format", "csv", "--db", db]),
        "d3il tables",
    );
    assert!(main.contains(",BC-MLP,reported,"), "{main}");
    assert!(!main.contains(",evaluated,"), "{main}");
}

/// The shipped zoo passes `d3il zoo check` (every cell's files are the ones
/// its provenance names) and keeps within its stated size budget, which the
/// check prints.
#[test]
fn the_shipped_zoo_checks_and_keeps_within_its_size_budget() {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/zoo");
    let out = d3il(&["zoo", "check", "--zoo", assets.to_str().unwrap()]);
    let text = succeeded(&out, "d3il zoo check");
    assert!(text.contains(", 0 skipped; "), "{text}");
    assert!(
        text.contains("MB of the zoo's size budget of 110 MB"),
        "{text}"
    );
    let bytes = d3il_server::zoo::size_bytes(&assets).unwrap();
    assert!(bytes <= d3il_server::zoo::SIZE_BUDGET_BYTES, "{bytes}");
}

/// A zoo over its size budget is refused, saying by how much and what to do
/// (a sparse file makes the bytes without writing them).
#[test]
fn check_refuses_a_zoo_over_its_size_budget() {
    let dir = scratch("over-budget");
    let cell = dir.join(CELL);
    std::fs::create_dir_all(&cell).unwrap();
    for e in std::fs::read_dir(fixture().join(CELL)).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, cell.join(p.file_name().unwrap())).unwrap();
    }
    let pad = std::fs::File::create(dir.join("padding.bin")).unwrap();
    pad.set_len(d3il_server::zoo::SIZE_BUDGET_BYTES).unwrap();
    let out = d3il(&["zoo", "check", "--zoo", dir.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("over its size budget of 110 MB") && err.contains("state a new budget"),
        "{err}"
    );
}

#[test]
fn check_reads_every_cell_and_names_a_tampered_one() {
    let ok = succeeded(
        &d3il(&["zoo", "check", "--zoo", fixture().to_str().unwrap()]),
        "d3il zoo check",
    );
    assert!(
        ok.contains(&format!("ok      {CELL}: BC-MLP seed 0")),
        "{ok}"
    );

    let dir = scratch("check");
    let cell = dir.join(CELL);
    std::fs::create_dir_all(&cell).unwrap();
    for e in std::fs::read_dir(fixture().join(CELL)).unwrap() {
        let p = e.unwrap().path();
        std::fs::copy(&p, cell.join(p.file_name().unwrap())).unwrap();
    }
    let mut r = std::fs::read(cell.join("result.json")).unwrap();
    r.push(b'\n');
    std::fs::write(cell.join("result.json"), r).unwrap();
    let bad = d3il(&["zoo", "check", "--zoo", dir.to_str().unwrap()]);
    assert!(!bad.status.success());
    let text = String::from_utf8_lossy(&bad.stdout);
    assert!(
        text.contains("skipped") && text.contains("result.json"),
        "{text}"
    );
}

#[test]
fn reeval_writes_what_moved() {
    let dir = scratch("reeval");
    let out = dir.join("drift.md");
    let o = d3il(&[
        "zoo",
        "reeval",
        "--zoo",
        fixture().to_str().unwrap(),
        "--out",
        out.to_str().unwrap(),
    ]);
    succeeded(&o, "d3il zoo reeval");
    let md = std::fs::read_to_string(&out).unwrap();
    assert!(md.starts_with("# Zoo version drift"), "{md}");
    let line = md
        .lines()
        .find(|l| l.starts_with(&format!("| {CELL} | BC-MLP |")))
        .unwrap_or_else(|| panic!("no row of the cell in\n{md}"));
    // The same deterministic policy on the same states, by the build that
    // made the result: nothing moved (another build may move it).
    if line.contains("(this build)") {
        assert!(line.ends_with("| no |"), "{line}");
    }
    assert!(md.contains("1 cells re-evaluated"), "{md}");
}

/// Issue 50, "a sampled zoo rollout replays bit for bit": one rollout of
/// every shipped zoo cell (assets/zoo) and of the fixture, chosen by the
/// cell's name, replays from its record (`d3il replay` checks every step's
/// physics state, the outcome and the final poses).
#[test]
fn a_sampled_rollout_of_every_zoo_cell_replays_bit_for_bit() {
    let assets = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/zoo");
    let mut cells = d3il_server::zoo::cell_dirs(&fixture());
    cells.extend(d3il_server::zoo::cell_dirs(&assets));
    assert!(!cells.is_empty());
    for cell in cells {
        // `d3il replay --result` reads plain JSON; a shipped cell's may be gzipped.
        let text = d3il_server::zoo::read_document(&cell, "result.json").unwrap();
        let tmp = d3il_test_support::TempDir::new("zoo-replay");
        let result = tmp.path().join("result.json");
        std::fs::write(&result, &text).unwrap();
        let doc: serde_json::Value = serde_json::from_slice(&text).unwrap();
        let rollouts = doc["rollouts"].as_array().cloned().unwrap_or_default();
        assert!(!rollouts.is_empty(), "{}: no rollouts", cell.display());
        // A shipped result keeps the traces of a sample of its rollouts
        // (scripts/zoo/pack.py: the first of each initial state, 60 in all;
        // a policy simulated once per state has one trace per state): the
        // choice is among those.
        let traced: Vec<usize> = (0..rollouts.len())
            .filter(|&i| !rollouts[i]["trace"].is_null())
            .collect();
        for r in &rollouts {
            assert!(
                r["rollout_index"] != 0 || !r["trace"].is_null(),
                "{}: rollout 0 of state {} has no trace",
                cell.display(),
                r["context_index"]
            );
        }
        // A fixed choice per cell (FNV-1a of `<task>/<dir>`).
        let name = cell
            .iter()
            .rev()
            .take(2)
            .map(|c| c.to_string_lossy().into_owned())
            .collect::<Vec<_>>()
            .join("/");
        let h = name.bytes().fold(0xcbf29ce484222325u64, |h, b| {
            (h ^ b as u64).wrapping_mul(0x100000001b3)
        });
        let k = traced[(h % traced.len() as u64) as usize].to_string();
        let out = succeeded(
            &d3il(&[
                "replay",
                "--result",
                result.to_str().unwrap(),
                "--rollout",
                &k,
            ]),
            "d3il replay",
        );
        assert!(
            out.contains("replays bit for bit"),
            "{}: rollout {k}: {out}",
            cell.display()
        );
    }
}

/// A robustness document replayed without `--level` says to name a level
/// and lists the document's levels (not serde's "missing field `manifest`");
/// with `--level AXIS/0` its control rollout replays bit for bit.
#[test]
fn replay_of_a_robustness_document_asks_for_a_level() {
    let cell = Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/zoo/aligning/bc-mlp-s0");
    let text = d3il_server::zoo::read_document(&cell, "robustness.json").unwrap();
    let tmp = d3il_test_support::TempDir::new("zoo-replay-level");
    let doc = tmp.path().join("robustness.json");
    std::fs::write(&doc, &text).unwrap();
    let doc = doc.to_str().unwrap();
    let out = d3il(&["replay", "--result", doc, "--rollout", "0"]);
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--level AXIS/LEVEL") && err.contains("latency/1"),
        "{err}"
    );
    assert!(!err.contains("missing field"), "{err}");
    let out = succeeded(
        &d3il(&[
            "replay",
            "--result",
            doc,
            "--level",
            "latency/0",
            "--rollout",
            "0",
        ]),
        "d3il replay",
    );
    assert!(out.contains("replays bit for bit"), "{out}");
}
