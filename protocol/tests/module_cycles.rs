//! The modules of `protocol/src` depend on each other in one direction only
//! (issue 21): a `crate::a` reference in `b.rs` and a `crate::b` reference in
//! `a.rs` (or any longer loop) fails this test.

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

/// Module name -> the sibling modules its source names as `crate::<name>`.
fn module_graph(src: &Path) -> BTreeMap<String, BTreeSet<String>> {
    let mut names = BTreeSet::new();
    let mut texts = BTreeMap::new();
    for entry in std::fs::read_dir(src).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_some_and(|e| e == "rs") {
            let name = path.file_stem().unwrap().to_string_lossy().into_owned();
            texts.insert(name.clone(), std::fs::read_to_string(&path).unwrap());
            names.insert(name);
        }
    }
    texts
        .into_iter()
        .filter(|(name, _)| name != "lib")
        .map(|(name, text)| {
            let deps = names
                .iter()
                .filter(|other| *other != &name && *other != "lib")
                .filter(|other| {
                    text.contains(&format!("crate::{other}::"))
                        || text.contains(&format!("crate::{other}}}"))
                        || text.contains(&format!("crate::{other};"))
                        || text.contains(&format!("crate::{other},"))
                })
                .cloned()
                .collect();
            (name, deps)
        })
        .collect()
}

/// A cycle through the graph, if any (depth-first search).
fn find_cycle(g: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        g: &BTreeMap<String, BTreeSet<String>>,
        node: &str,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == node) {
            let mut cycle = path[i..].to_vec();
            cycle.push(node.to_string());
            return Some(cycle);
        }
        if done.contains(node) {
            return None;
        }
        path.push(node.to_string());
        for dep in g.get(node).into_iter().flatten() {
            if let Some(c) = visit(g, dep, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(node.to_string());
        None
    }
    let mut done = BTreeSet::new();
    for node in g.keys() {
        if let Some(c) = visit(g, node, &mut Vec::new(), &mut done) {
            return Some(c);
        }
    }
    None
}

#[test]
fn protocol_modules_have_no_cycle() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let g = module_graph(&src);
    assert!(g.contains_key("job") && g.contains_key("results"), "{g:?}");
    // The dependency that used to close the loop is gone, the other remains.
    assert!(g["job"].contains("results"), "{g:?}");
    assert!(!g["results"].contains("job"), "{g:?}");
    assert_eq!(find_cycle(&g), None, "module graph: {g:?}");
}

#[test]
fn the_cycle_finder_finds_cycles() {
    let g: BTreeMap<String, BTreeSet<String>> = [
        ("a", vec!["b"]),
        ("b", vec!["c"]),
        ("c", vec!["a"]),
        ("d", vec![]),
    ]
    .into_iter()
    .map(|(k, v)| (k.to_string(), v.into_iter().map(String::from).collect()))
    .collect();
    assert_eq!(
        find_cycle(&g),
        Some(vec!["a".into(), "b".into(), "c".into(), "a".into()])
    );
}
