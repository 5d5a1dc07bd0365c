//! The server's module layout: dependencies point one way. Each module's
//! references to `crate::…` (in `use` lines and inline paths) are read from
//! the source, and the graph they form must have no cycle; the three HTTP
//! front ends (`http::api`, `http::pages`, `http::plots`) must not reference
//! each other; `leaderboard` stays free of HTTP and SQL; `error` references
//! nothing but the store's error. Also: no file under `server/` is over 700
//! lines, and store transactions begin through `begin_write!`. References
//! are read by the workspace's checker (`d3il_test_support::layout`, whose
//! own tests and the workspace-wide rules are in
//! test-support/tests/layout.rs); a file's inline test module is not part of
//! the graph.

use d3il_test_support::layout::{module_of, referenced_paths};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

fn src_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The graph node of a source file: the top-level module, or for `http` the
/// front end (`http::api`, `http::pages`, …) it belongs to.
fn node_of(rel: &Path) -> String {
    let parts: Vec<String> = rel
        .with_extension("")
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    match parts.as_slice() {
        [top] => top.clone(),
        [first, second, ..] if first == "http" && second != "mod" => format!("http::{second}"),
        [first, ..] => first.clone(),
        [] => unreachable!(),
    }
}

/// The node a `crate::` path names (`a::b::c` -> `a`, or `http::b`).
fn node_of_path(path: &[&str]) -> Option<String> {
    let first = *path.first()?;
    if first == "http" {
        return Some(match path.get(1) {
            Some(second) if second.chars().all(|c| c.is_ascii_lowercase() || c == '_') => {
                format!("http::{second}")
            }
            _ => "http".into(),
        });
    }
    Some(first.to_string())
}

/// Every module named after `crate::` (or `self::`/`super::`) in `text`,
/// read by the workspace's layout checker (comments and the trailing inline
/// test module skipped), as graph nodes.
fn references(text: &str, here: &[String]) -> BTreeSet<String> {
    referenced_paths(text, here)
        .iter()
        .filter_map(|p| {
            let p: Vec<&str> = p.iter().map(String::as_str).collect();
            node_of_path(&p)
        })
        .collect()
}

fn graph() -> BTreeMap<String, BTreeSet<String>> {
    let root = src_dir();
    let mut files = vec![];
    rust_files(&root, &mut files);
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in files {
        let rel = f.strip_prefix(&root).unwrap().to_path_buf();
        let node = node_of(&rel);
        if node == "lib" {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        let refs = references(&text, &module_of(&rel));
        let e = g.entry(node.clone()).or_default();
        for r in refs {
            // A module's own files, and `http` (only mod declarations and
            // the router) referring to its children, are not edges.
            if r != node && !(node == "http" && r.starts_with("http::")) {
                e.insert(r);
            }
        }
    }
    g
}

/// A cycle in `g`, if there is one (depth-first search).
fn find_cycle(g: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        n: &str,
        g: &BTreeMap<String, BTreeSet<String>>,
        state: &mut BTreeMap<String, u8>,
        stack: &mut Vec<String>,
    ) -> Option<Vec<String>> {
        match state.get(n) {
            Some(2) => return None,
            Some(1) => {
                let start = stack.iter().position(|s| s == n).unwrap_or(0);
                let mut cycle = stack[start..].to_vec();
                cycle.push(n.to_string());
                return Some(cycle);
            }
            _ => {}
        }
        state.insert(n.to_string(), 1);
        stack.push(n.to_string());
        for m in g.get(n).into_iter().flatten() {
            if let Some(c) = visit(m, g, state, stack) {
                return Some(c);
            }
        }
        stack.pop();
        state.insert(n.to_string(), 2);
        None
    }
    let mut state = BTreeMap::new();
    for n in g.keys() {
        if let Some(c) = visit(n, g, &mut state, &mut vec![]) {
            return Some(c);
        }
    }
    None
}

#[test]
fn the_parser_reads_use_lines_and_inline_paths() {
    let refs = references(
        "use crate::store::{Store, X};\nuse crate::{auth::Authed, http::extract::Param};\n\
         fn f() { crate::leaderboard::board_for(); } // crate::app is a comment\nuse d3il_crate::x;\n\
         #[cfg(test)]\nmod tests {\n    use crate::views::X;\n}\n",
        &[],
    );
    let want: BTreeSet<String> = ["store", "auth", "http::extract", "leaderboard"]
        .into_iter()
        .map(String::from)
        .collect();
    assert_eq!(refs, want);
    let mut g = BTreeMap::new();
    g.insert("a".to_string(), BTreeSet::from(["b".to_string()]));
    g.insert("b".to_string(), BTreeSet::from(["a".to_string()]));
    assert!(find_cycle(&g).is_some(), "a two-module cycle is found");
}

#[test]
fn server_modules_have_no_cycle() {
    let g = graph();
    assert!(
        g.contains_key("http::api") && g.contains_key("store"),
        "{g:?}"
    );
    if let Some(cycle) = find_cycle(&g) {
        panic!(
            "module cycle in server/src: {}; move what both need into a module below them",
            cycle.join(" -> ")
        );
    }
}

#[test]
fn front_ends_do_not_import_each_other_and_lower_layers_stay_low() {
    let g = graph();
    let fronts = ["http::api", "http::pages", "http::plots"];
    for f in fronts {
        for other in fronts.iter().filter(|o| **o != f) {
            assert!(
                !g[f].contains(*other),
                "{f} imports {other}; share through leaderboard, views or http::extract"
            );
        }
    }
    for low in ["leaderboard", "error", "store"] {
        for r in &g[low] {
            assert!(
                !r.starts_with("http")
                    && !["app", "state", "views", "auth", "intake"].contains(&r.as_str()),
                "{low} depends on {r}, a layer above it"
            );
        }
    }
    let error_deps: Vec<&String> = g["error"].iter().collect();
    assert_eq!(
        error_deps,
        vec!["store"],
        "error.rs depends only on the store's error"
    );
    // Pure: no HTTP framework and no SQL in the leaderboard module.
    let text = std::fs::read_to_string(src_dir().join("leaderboard.rs")).unwrap();
    assert!(!text.contains("axum") && !text.contains("sqlx"));
}

#[test]
fn no_file_over_700_lines() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = vec![];
    for dir in ["src", "tests"] {
        rust_files(&root.join(dir), &mut files);
    }
    for f in files {
        let n = std::fs::read_to_string(&f).unwrap().lines().count();
        assert!(n <= 700, "{} has {n} lines; split it by job", f.display());
    }
}

/// Every store transaction that writes begins through `begin_write!`: on
/// SQLite a deferred transaction that reads and then writes fails with
/// SQLITE_BUSY_SNAPSHOT when another connection wrote in between, which no
/// busy timeout retries. Only PostgreSQL-only code (the advisory lock in
/// files.rs, a PostgreSQL pool) may call `.begin()` itself.
#[test]
fn store_transactions_begin_through_begin_write() {
    let mut files = vec![];
    rust_files(&src_dir().join("store"), &mut files);
    for f in files {
        if f.ends_with("store/mod.rs") || f.ends_with("store/files.rs") {
            continue;
        }
        let text = std::fs::read_to_string(&f).unwrap();
        for (i, line) in text.lines().enumerate() {
            assert!(
                !line.contains(".begin()"),
                "{}:{}: begin the transaction with begin_write!(self, pool)",
                f.display(),
                i + 1
            );
        }
    }
}
