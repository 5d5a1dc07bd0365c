//! `d3il eval --shard K/N` + `d3il merge` through the real binary: the merged
//! result equals a plain `d3il eval --json` bit for bit (every metric and
//! rollout record; only the measured inference time differs), and bad sets
//! of parts are refused with a message that says what is wrong.
//!
//! The policy is `scripted:pushing:all-modes`, which picks its pushing mode
//! from the rollout id (id mod 4): a shard that numbered its rollouts from 0
//! instead of globally would push in other modes and change the behaviours.

use crate::shard_support;

use d3il_test_support::{refused, succeeded};
use serde_json::Value;
use shard_support::{assert_same_result, table};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::sync::OnceLock;

const POLICY: &str = "scripted:pushing:all-modes";

fn d3il(args: &[&str], dir: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_d3il"))
        .args(args)
        .current_dir(dir)
        .env("RUST_BACKTRACE", "0")
        .output()
        .unwrap()
}

fn eval_args<'a>(policy: &'a str, extra: &[&'a str]) -> Vec<&'a str> {
    let mut a = vec![
        "eval",
        "--task",
        "pushing",
        "--policy",
        policy,
        "--protocol",
        "quick",
        "--seed",
        "7",
    ];
    a.extend_from_slice(extra);
    a
}

/// A plain evaluation and its 3 shards, run once for all tests here.
struct Fixture {
    dir: PathBuf,
    plain_stdout: String,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        // Cargo's scratch space for integration tests (a static is never
        // dropped, so nothing under /tmp would be removed).
        let dir = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("shard-cli");
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let plain_stdout = succeeded(
            &d3il(&eval_args(POLICY, &["--json", "plain.json"]), &dir),
            "plain eval",
        );
        for k in 1..=3 {
            let shard = format!("{k}/3");
            let file = format!("part{k}.json");
            succeeded(
                &d3il(
                    &eval_args(POLICY, &["--shard", &shard, "--json", &file]),
                    &dir,
                ),
                "shard eval",
            );
        }
        Fixture { dir, plain_stdout }
    })
}

#[test]
fn three_shards_merge_to_the_plain_evaluation() {
    let f = fixture();
    // Any order of the part files.
    let stdout = succeeded(
        &d3il(
            &[
                "merge",
                "part3.json",
                "part1.json",
                "part2.json",
                "--json",
                "merged3.json",
            ],
            &f.dir,
        ),
        "merge",
    );
    assert_same_result(&f.dir.join("plain.json"), &f.dir.join("merged3.json"));
    // The same table as `d3il eval` prints.
    assert_eq!(table(&stdout), table(&f.plain_stdout));
    assert!(stdout.contains("success rate"), "{stdout}");
}

#[test]
fn two_uneven_shards_merge_to_the_plain_evaluation() {
    let f = fixture();
    let dir = f.dir.join("two");
    std::fs::create_dir_all(&dir).unwrap();
    for k in 1..=2 {
        let shard = format!("{k}/2");
        let file = format!("half{k}.json");
        let out = succeeded(
            &d3il(
                &eval_args(POLICY, &["--shard", &shard, "--json", &file]),
                &dir,
            ),
            "shard eval",
        );
        assert!(out.contains(&format!("shard {k}/2")), "{out}");
    }
    // Shard 2/2 holds initial states 1 and 2 (global rollout ids 2..6).
    let half2: Value =
        serde_json::from_slice(&std::fs::read(dir.join("half2.json")).unwrap()).unwrap();
    assert_eq!(half2["contexts"], serde_json::json!([1, 3]));
    assert_eq!(half2["manifest"]["n_contexts"], 3);
    succeeded(
        &d3il(
            &["merge", "half1.json", "half2.json", "--json", "merged.json"],
            &dir,
        ),
        "merge",
    );
    assert_same_result(&f.dir.join("plain.json"), &dir.join("merged.json"));
}

/// A shard run in the sandboxed worker (`--sandbox`, as the server's worker
/// hosts run shards) writes the same part as the in-process shard.
#[test]
fn a_sandboxed_shard_writes_the_same_part() {
    let f = fixture();
    let dir = f.dir.join("sandboxed");
    std::fs::create_dir_all(&dir).unwrap();
    succeeded(
        &d3il(
            &eval_args(
                POLICY,
                &["--shard", "2/3", "--sandbox", "--json", "part2.json"],
            ),
            &dir,
        ),
        "sandboxed shard eval",
    );
    let read = |p: PathBuf| -> Value {
        let mut v: Value = serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap();
        v["policy_seconds"] = Value::Null;
        v
    };
    let (boxed, plain) = (read(dir.join("part2.json")), read(f.dir.join("part2.json")));
    assert_eq!(boxed["contexts"], serde_json::json!([1, 2]));
    assert_eq!(boxed, plain);
}

/// Writes a copy of `part` with `edit` applied to its JSON.
fn edited(dir: &Path, part: &str, name: &str, edit: impl FnOnce(&mut Value)) -> String {
    let mut v: Value = serde_json::from_slice(&std::fs::read(dir.join(part)).unwrap()).unwrap();
    edit(&mut v);
    std::fs::write(dir.join(name), serde_json::to_vec(&v).unwrap()).unwrap();
    name.to_string()
}

#[test]
fn merge_refuses_parts_that_do_not_make_one_evaluation() {
    let f = fixture();
    let dir = &f.dir;
    let merge = |files: &[&str]| {
        let mut a = vec!["merge"];
        a.extend_from_slice(files);
        refused(&d3il(&a, dir), &format!("merge {files:?}"))
    };

    let e = merge(&["part1.json", "part3.json"]);
    assert!(e.contains("missing shard 2/3"), "{e}");
    let e = merge(&["part1.json", "part2.json", "part2.json", "part3.json"]);
    assert!(e.contains("shard 2/3 is given twice"), "{e}");

    // A shard of another policy (really evaluated).
    succeeded(
        &d3il(
            &eval_args(
                "scripted:pushing:mode=0",
                &["--shard", "2/3", "--json", "other-policy.json"],
            ),
            dir,
        ),
        "shard eval",
    );
    let e = merge(&["part1.json", "other-policy.json", "part3.json"]);
    assert!(
        e.contains("different policies") && e.contains("policy_sha256"),
        "{e}"
    );

    let set = edited(dir, "part2.json", "other-set.json", |v| {
        v["manifest"]["initial_states_sha256"] = "00".repeat(32).into();
    });
    let e = merge(&["part1.json", &set, "part3.json"]);
    assert!(e.contains("different initial-state sets"), "{e}");

    // A part from a host without the Panda meshes draws another scene.
    let look = edited(dir, "part2.json", "other-look.json", |v| {
        v["manifest"]["robot_look"] = "primitives".into();
        v["manifest"]["mjcf_sha256"] = "11".repeat(32).into();
    });
    let e = merge(&["part1.json", &look, "part3.json"]);
    assert!(
        e.contains("different robot looks") && e.contains("robot_look") && e.contains("./dev"),
        "{e}"
    );

    let seed = edited(dir, "part2.json", "other-seed.json", |v| {
        v["manifest"]["seed"] = 8.into();
    });
    let e = merge(&["part1.json", &seed, "part3.json"]);
    assert!(
        e.contains("different protocols") && e.contains("seed"),
        "{e}"
    );

    let cut = edited(dir, "part2.json", "cut.json", |v| {
        v["rollouts"].as_array_mut().unwrap().pop();
    });
    let e = merge(&["part1.json", &cut, "part3.json"]);
    assert!(e.contains("inconsistent"), "{e}");

    // A plain result is not a part.
    let e = merge(&["plain.json"]);
    assert!(e.contains("is not a part file"), "{e}");
}

#[test]
fn eval_refuses_bad_shards() {
    let dir = std::env::temp_dir();
    let e = refused(
        &d3il(
            &eval_args(POLICY, &["--shard", "4/4", "--json", "x.json"]),
            &dir,
        ),
        "4 shards of 3 initial states",
    );
    assert!(e.contains("at most 3 shards"), "{e}");
    let e = refused(
        &d3il(
            &eval_args(POLICY, &["--shard", "0/3", "--json", "x.json"]),
            &dir,
        ),
        "shard 0/3",
    );
    assert!(e.contains("K/N with 1 <= K <= N"), "{e}");
    let e = refused(
        &d3il(&eval_args(POLICY, &["--shard", "1/3"]), &dir),
        "no --json",
    );
    assert!(e.contains("needs --json"), "{e}");
}
