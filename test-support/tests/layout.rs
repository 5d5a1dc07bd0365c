//! The layout rules hold in every crate of the workspace: no hand-written
//! Rust file is over 700 lines (generated files are exempt by name, in
//! `d3il_test_support::layout::GENERATED`), and no crate's modules refer to
//! each other in a cycle; and the `d3il` binary (`src/`) does not reach into
//! the server's store (it uses `d3il_server::ops`, the store's types the
//! command-line tools need, and the server's `cli` functions), and its
//! command modules (`src/cmd/`) and benchmarks (`src/bench/`) use the common
//! module (`src/common/`), never another command's module or each other. The checker
//! itself is tested on synthetic input first, so that a rule that silently
//! stopped looking would fail here.
//! (server/tests/app/layout.rs adds the server's own rules: front ends apart,
//! lower layers low.)

use d3il_test_support::layout::{
    crate_graph, cycles, graph_of, imports_between, long_files, paths_into, referenced_paths,
    rust_files, sibling_imports, workspace_crates, GENERATED, MAX_LINES,
};
use d3il_test_support::{repo_dir, TempDir};
use std::collections::BTreeSet;

fn m(path: &str) -> Vec<String> {
    path.split("::").map(String::from).collect()
}

#[test]
fn the_checker_reads_every_kind_of_module_path() {
    let text = "use crate::store::{Store, jobs::{Job, Queue}};\n\
        use super::merge::run_shard as shard;\nuse super::super::top;\n\
        use self::child::X;\nfn f() { crate::leaderboard::board_for(); } // crate::app is a comment\n\
        use d3il_crate::x; macro_rules! m { () => { $crate::y::z } }\n\
        #[cfg(test)]\nmod tests {\n    use crate::only_in_tests;\n}\n";
    let got = referenced_paths(text, &m("cmd::eval"));
    let want: BTreeSet<Vec<String>> = [
        "store::Store",
        "store::jobs::Job",
        "store::jobs::Queue",
        "cmd::merge::run_shard",
        "top",
        "cmd::eval::child::X",
        "leaderboard::board_for",
    ]
    .into_iter()
    .map(m)
    .collect();
    assert_eq!(got, want);
}

#[test]
fn the_checker_finds_a_new_cycle_and_ignores_parents_and_children() {
    let files = |eval: &str| {
        vec![
            (
                m("cmd"),
                "pub mod eval; pub mod merge; use self::eval::run;".to_string(),
            ),
            (m("cmd::eval"), eval.to_string()),
            (m("cmd::merge"), "use super::eval::run_shard;".to_string()),
            (m("cmd::shard"), "use super::Args;".to_string()),
        ]
    };
    let acyclic = graph_of(&files("use super::shard::Args; use crate::cmd::Cli;"));
    assert_eq!(cycles(&acyclic), Vec::<Vec<String>>::new(), "{acyclic:?}");
    let cyclic = graph_of(&files("use super::merge::merge_parts;"));
    assert_eq!(
        cycles(&cyclic),
        vec![vec![
            "cmd::eval".to_string(),
            "cmd::merge".into(),
            "cmd::eval".into()
        ]]
    );
    // A longer cycle through three modules is found too.
    let three = graph_of(&[
        (m("a"), "use crate::b::x;".into()),
        (m("b"), "use crate::c::y;".into()),
        (m("c"), "fn f() { crate::a::z(); }".into()),
    ]);
    assert_eq!(cycles(&three), vec![m("a::b::c::a")]);
}

#[test]
fn the_checker_refuses_a_701_line_file_and_reads_the_real_crates() {
    let dir = TempDir::new("layout");
    let src = dir.path().join("src");
    std::fs::create_dir_all(src.join("a")).unwrap();
    std::fs::write(src.join("lib.rs"), "pub mod a;\n").unwrap();
    std::fs::write(src.join("a/mod.rs"), "pub mod b;\nuse crate::c::X;\n").unwrap();
    std::fs::write(src.join("a/b.rs"), "use super::super::c::Y;\n").unwrap();
    std::fs::write(
        src.join("c.rs"),
        "pub use crate::a::b::Z;\n".repeat(MAX_LINES),
    )
    .unwrap();
    std::fs::write(src.join("d.rs"), "//\n".repeat(MAX_LINES + 1)).unwrap();
    let files = rust_files(dir.path());
    let long = long_files(dir.path(), &files, MAX_LINES, &[]);
    assert_eq!(long, vec![("src/d.rs".to_string(), MAX_LINES + 1)]);
    assert!(long_files(dir.path(), &files, MAX_LINES, &["src/d.rs"]).is_empty());
    assert_eq!(
        cycles(&crate_graph(&src)),
        vec![vec!["a::b".to_string(), "c".into(), "a::b".into()]]
    );

    let crates = workspace_crates(&repo_dir());
    for name in [
        "evaluator",
        "server",
        "tables",
        "metrics",
        "policy",
        "protocol",
    ] {
        assert!(
            crates.iter().any(|c| c.ends_with(name)),
            "{name} in {crates:?}"
        );
    }
    let g = crate_graph(&repo_dir().join("evaluator/src"));
    assert!(g["mujoco::view"].contains("mujoco"), "{g:?}");
}

#[test]
fn no_hand_written_file_is_over_700_lines() {
    let root = repo_dir();
    let mut long = vec![];
    for dir in workspace_crates(&root) {
        let files: Vec<_> = ["src", "tests", "benches", "examples", "build.rs"]
            .iter()
            .flat_map(|d| {
                rust_files(&dir.join(d))
                    .into_iter()
                    .chain(Some(dir.join(d)).filter(|p| p.is_file()))
            })
            .collect();
        long.extend(long_files(&root, &files, MAX_LINES, GENERATED));
    }
    assert!(
        long.is_empty(),
        "files over {MAX_LINES} lines (split each by job; a generated file goes into \
         layout::GENERATED): {long:?}"
    );
}

#[test]
fn no_crate_has_a_module_cycle() {
    let root = repo_dir();
    let mut found = vec![];
    for dir in workspace_crates(&root) {
        let g = crate_graph(&dir.join("src"));
        for c in cycles(&g) {
            found.push(format!(
                "{}: {}",
                if dir == root {
                    "d3il".into()
                } else {
                    dir.file_name().unwrap().to_string_lossy()
                },
                c.join(" -> ")
            ));
        }
    }
    assert!(
        found.is_empty(),
        "module cycles (move what both sides need into a module below them):\n{}",
        found.join("\n")
    );
}

#[test]
fn the_checker_finds_every_way_of_naming_the_servers_store() {
    let store = |text: &str| {
        paths_into(text, "d3il_server")
            .into_iter()
            .filter(|p| p[0] == "store")
            .map(|p| p.join("::"))
            .collect::<Vec<_>>()
    };
    assert_eq!(store("use d3il_server::store::Store;"), ["store::Store"]);
    assert_eq!(
        store("use d3il_server::{cli, store::{DbTarget, sqlx}};"),
        ["store::DbTarget", "store::sqlx"]
    );
    assert_eq!(store("use d3il_server::store;"), ["store"]);
    assert_eq!(
        store("fn f() { d3il_server::store::Store::connect(); }"),
        ["store::Store::connect"]
    );
    assert_eq!(
        store("#[cfg(test)]\nmod tests {\n    use d3il_server::store::NewMethod;\n}\n"),
        ["store::NewMethod"]
    );
    assert!(store("use d3il_server::ops::Store; // not d3il_server::store").is_empty());
    assert!(store("use my_d3il_server::store::X;").is_empty());
}

#[test]
fn the_binary_does_not_import_the_servers_store() {
    let root = repo_dir();
    let mut found = vec![];
    for file in rust_files(&root.join("src")) {
        let text = std::fs::read_to_string(&file).unwrap();
        for p in paths_into(&text, "d3il_server") {
            if p[0] == "store" {
                let rel = file.strip_prefix(&root).unwrap().display().to_string();
                found.push(format!("{rel}: d3il_server::{}", p.join("::")));
            }
        }
    }
    assert!(
        found.is_empty(),
        "src/ names the server's store (use d3il_server::ops, which re-exports what the \
         command-line tools need, or a d3il_server::cli function; add a re-export there if \
         one is missing):\n{}",
        found.join("\n")
    );
}

/// The edges of the `d3il` binary's module graph `g` that break its shape:
/// a command module naming another command's module (or `src/cmd/mod.rs`),
/// and the commands and the benchmarks naming each other.
fn shell_violations(g: &d3il_test_support::layout::Graph) -> Vec<String> {
    let mut found = sibling_imports(g, "cmd");
    found.extend(imports_between(g, "cmd", "bench"));
    found
        .into_iter()
        .map(|(from, to)| format!("{from} -> {to}"))
        .collect()
}

#[test]
fn the_checker_finds_a_command_naming_another_command_or_a_benchmark() {
    let files = |race: &str, submit_race: &str, chaos: &str| {
        vec![
            (
                m("cmd"),
                "pub mod eval; pub mod race; pub mod submit;".to_string(),
            ),
            (
                m("cmd::eval"),
                "use crate::common::evaluation::build_job;\n\
                 #[cfg(test)]\nmod tests {\n    use super::*;\n}\n"
                    .to_string(),
            ),
            (m("cmd::race"), race.to_string()),
            (
                m("cmd::submit"),
                "pub mod race;\nuse self::race::run;".to_string(),
            ),
            (m("cmd::submit::race"), submit_race.to_string()),
            (m("common"), "pub mod evaluation;".to_string()),
            (
                m("common::evaluation"),
                "use super::assets_dir;".to_string(),
            ),
            (m("bench"), "mod chaos; mod procs;".to_string()),
            (
                m("bench::procs"),
                "use crate::common::assets_dir;".to_string(),
            ),
            (m("bench::chaos"), chaos.to_string()),
        ]
    };
    let found = |race: &str, submit_race: &str, chaos: &str| {
        shell_violations(&graph_of(&files(race, submit_race, chaos)))
    };
    // Allowed: the common module, a command's own submodules and their
    // parent, one benchmark using another.
    assert_eq!(
        found(
            "use crate::common::{evaluation::{build_job, EvalArgs}, text};",
            "use super::Args; fn f() { super::client_of(); crate::common::text::race(); }",
            "use super::procs::spawn_ready; use crate::common::flags::Look;",
        ),
        Vec::<String>::new()
    );
    // Another command, by `super::` and by `crate::cmd::`, in a use line or in code.
    assert_eq!(
        found("use super::eval::build_job;", "", ""),
        ["cmd::race -> cmd::eval"]
    );
    assert_eq!(
        found("fn f() { crate::cmd::eval::run(); }", "", ""),
        ["cmd::race -> cmd::eval"]
    );
    assert_eq!(
        found("use super::{eval::EvalArgs, submit::race::run};", "", ""),
        ["cmd::race -> cmd::eval", "cmd::race -> cmd::submit::race"]
    );
    // What `src/cmd/mod.rs` itself holds, and a command's submodule reaching
    // past its command.
    assert_eq!(
        found("use super::check_output_path;", "", ""),
        ["cmd::race -> cmd"]
    );
    assert_eq!(
        found("", "use super::super::race::render;", ""),
        ["cmd::submit::race -> cmd::race"]
    );
    assert_eq!(
        found("", "fn f() { crate::cmd::eval::run(); }", ""),
        ["cmd::submit::race -> cmd::eval"]
    );
    // The commands and the benchmarks, either way.
    assert_eq!(
        found("use crate::bench::procs::spawn_ready;", "", ""),
        ["cmd::race -> bench::procs"]
    );
    assert_eq!(
        found("", "", "use crate::cmd::eval::EvalArgs;"),
        ["bench::chaos -> cmd::eval"]
    );
    assert_eq!(
        found("", "", "fn f() { super::super::cmd::race::run(); }"),
        ["bench::chaos -> cmd::race"]
    );
}

#[test]
fn the_binarys_commands_use_only_the_common_module_and_the_benchmarks_stand_apart() {
    let g = crate_graph(&repo_dir().join("src"));
    // The checker sees the crate as it is laid out (a renamed folder would
    // make this test pass vacuously).
    for module in ["cmd::eval", "cmd::race", "common", "bench", "bench::chaos"] {
        assert!(
            g.contains_key(module),
            "no module {module} in {:?}",
            g.keys()
        );
    }
    assert!(g["cmd::race"].contains("common::evaluation"), "{g:?}");
    let found = shell_violations(&g);
    assert!(
        found.is_empty(),
        "in src/, a command module names another command's module or src/cmd/mod.rs, or the \
         commands and the benchmarks name each other (move what both need into src/common/, \
         or into a library crate when it is a rule of the domain):\n{}",
        found.join("\n")
    );
}
