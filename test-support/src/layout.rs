//! The workspace's layout rules, as code the layout tests share: which Rust
//! files a crate has, how long they are, which of the crate's modules each
//! file refers to, and whether those references form a cycle.
//!
//! Modules are read from the source text, not from the compiler: a file is
//! the module its path names (`src/a/b.rs` and `src/a/b/mod.rs` are `a::b`,
//! or what a `#[path]` attribute makes of it), and its references are the
//! `crate::`, `self::` and `super::` paths in its `use` lines and in its code
//! (comments and the trailing `#[cfg(test)] mod tests { … }` block skipped).
//! A path names the longest known module it starts with. A module's
//! references to itself, to its own submodules (declaring and re-exporting
//! them) and to the crate root are not edges. On that graph the checker also
//! finds the edges that cross a boundary inside a crate: between the children
//! of one module ([`sibling_imports`]) and between two parts of a crate
//! ([`imports_between`]).

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The longest a hand-written file may be.
pub const MAX_LINES: usize = 700;

/// Files that are generated, not written by hand, and so exempt from
/// [`MAX_LINES`] (paths relative to the repository's root).
pub const GENERATED: &[&str] = &[
    // bindgen-style declarations of the MuJoCo 2.2 C API.
    "evaluator/src/mujoco/bindings.rs",
];

/// A module graph: each module (`a::b`) and the modules it refers to.
pub type Graph = BTreeMap<String, BTreeSet<String>>;

/// Every `.rs` file under `dir`, sorted (`target/` skipped).
pub fn rust_files(dir: &Path) -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            if p.is_dir() {
                if p.file_name().is_some_and(|n| n != "target") {
                    walk(&p, out);
                }
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    let mut out = vec![];
    walk(dir, &mut out);
    out.sort();
    out
}

/// The directories of the workspace's crates: the root package and every
/// `members` entry of the root `Cargo.toml`.
pub fn workspace_crates(root: &Path) -> Vec<PathBuf> {
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).expect("root Cargo.toml");
    let members = manifest
        .lines()
        .find(|l| l.trim_start().starts_with("members"))
        .expect("[workspace] members line");
    let mut out = vec![root.to_path_buf()];
    for name in members.split('"').skip(1).step_by(2) {
        out.push(root.join(name));
    }
    out
}

/// Files over `max` lines among `files`, with their lengths, except those
/// whose path relative to `root` is in `exempt`.
pub fn long_files(
    root: &Path,
    files: &[PathBuf],
    max: usize,
    exempt: &[&str],
) -> Vec<(String, usize)> {
    let mut out = vec![];
    for f in files {
        let rel = f
            .strip_prefix(root)
            .unwrap_or(f)
            .to_string_lossy()
            .into_owned();
        if exempt.contains(&rel.as_str()) {
            continue;
        }
        let n = std::fs::read_to_string(f)
            .map(|t| t.lines().count())
            .unwrap_or(0);
        if n > max {
            out.push((rel, n));
        }
    }
    out
}

/// The module a file under `src/` is, from its path relative to `src/`
/// (`lib.rs`, `main.rs` -> the crate root, `[]`).
pub fn module_of(rel: &Path) -> Vec<String> {
    let mut parts: Vec<String> = rel
        .with_extension("")
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if matches!(parts.last().map(String::as_str), Some("mod")) {
        parts.pop();
    }
    if parts.len() == 1 && (parts[0] == "lib" || parts[0] == "main") {
        parts.clear();
    }
    parts
}

/// `#[path = "f.rs"] mod name;` declarations in `text`: (file, module name).
fn path_attributes(text: &str) -> Vec<(String, String)> {
    let mut out = vec![];
    let mut lines = text.lines();
    while let Some(l) = lines.next() {
        let l = l.trim();
        let Some(rest) = l.strip_prefix("#[path") else {
            continue;
        };
        let Some(file) = rest.split('"').nth(1) else {
            continue;
        };
        for next in lines.by_ref() {
            let next = next.trim();
            if next.starts_with("#[") {
                continue;
            }
            let decl = next
                .trim_start_matches("pub(crate) ")
                .trim_start_matches("pub ");
            if let Some(m) = decl.strip_prefix("mod ") {
                out.push((file.to_string(), ident(m).to_string()));
            }
            break;
        }
    }
    out
}

fn ident(s: &str) -> &str {
    let end = s
        .find(|c: char| !(c.is_alphanumeric() || c == '_'))
        .unwrap_or(s.len());
    &s[..end]
}

/// `text` without comments and without a trailing inline test module (whose
/// `super::` means this file, and whose references are the tests').
fn code_of(text: &str) -> String {
    let mut lines: Vec<&str> = text.lines().collect();
    for i in 0..lines.len() {
        if lines[i].trim() == "#[cfg(test)]" {
            let next = lines[i + 1..]
                .iter()
                .map(|l| l.trim())
                .find(|l| !l.starts_with("#["));
            if next.is_some_and(|l| l.starts_with("mod ") && l.ends_with('{')) {
                lines.truncate(i);
                break;
            }
        }
    }
    lines
        .iter()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// The paths of a use tree at the start of `s` (`a::b`, `a::{b, c::{d}}`,
/// `a::*`), each as its segments; `as` renames and globs end a path.
fn use_tree(s: &str) -> Vec<Vec<String>> {
    fn tree(s: &[char], i: &mut usize, prefix: &[String], out: &mut Vec<Vec<String>>) {
        let skip_ws = |i: &mut usize| {
            while *i < s.len() && s[*i].is_whitespace() {
                *i += 1;
            }
        };
        let mut path = prefix.to_vec();
        loop {
            skip_ws(i);
            if *i < s.len() && s[*i] == '{' {
                *i += 1;
                loop {
                    skip_ws(i);
                    if *i >= s.len() {
                        return;
                    }
                    if s[*i] == '}' {
                        *i += 1;
                        return;
                    }
                    if s[*i] == ',' {
                        *i += 1;
                        continue;
                    }
                    let before = *i;
                    tree(s, i, &path, out);
                    // Skip what a tree leaves (`as x`, `*`) up to `,` or `}`.
                    while *i < s.len() && s[*i] != ',' && s[*i] != '}' {
                        if s[*i] == '{' {
                            break;
                        }
                        *i += 1;
                    }
                    if *i == before {
                        *i += 1;
                    }
                }
            }
            let start = *i;
            while *i < s.len() && (s[*i].is_alphanumeric() || s[*i] == '_') {
                *i += 1;
            }
            if *i == start {
                break;
            }
            path.push(s[start..*i].iter().collect());
            if s.get(*i) == Some(&':') && s.get(*i + 1) == Some(&':') {
                *i += 2;
            } else {
                break;
            }
        }
        if path.len() > prefix.len() {
            out.push(path);
        }
    }
    let chars: Vec<char> = s.chars().take(4000).collect();
    let mut out = vec![];
    tree(&chars, &mut 0, &[], &mut out);
    out
}

/// Every path `text` names through `crate::`, `self::` or `super::`, made
/// absolute (segments from the crate root) for a file that is module `here`.
pub fn referenced_paths(text: &str, here: &[String]) -> BTreeSet<Vec<String>> {
    let code = code_of(text);
    let mut out = BTreeSet::new();
    let bytes = code.as_bytes();
    for (i, _) in code.match_indices("::") {
        // The keyword just before this `::`.
        let head_start = code[..i]
            .rfind(|c: char| !(c.is_alphanumeric() || c == '_'))
            .map_or(0, |k| k + 1);
        let head = &code[head_start..i];
        if !matches!(head, "crate" | "self" | "super") {
            continue;
        }
        // Only the first keyword of a path: not `$crate::`, not `a::self::`,
        // not the second `super` of `super::super::`.
        let before = code[..head_start].trim_end();
        if head_start > 0 && bytes[head_start - 1] == b'$' || before.ends_with("::") {
            continue;
        }
        let mut base: Vec<String> = match head {
            "crate" => vec![],
            "self" => here.to_vec(),
            _ => here[..here.len().saturating_sub(1)].to_vec(),
        };
        let mut rest = &code[i + 2..];
        while let Some(r) = rest.strip_prefix("super::") {
            base.pop();
            rest = r;
        }
        for p in use_tree(rest) {
            let mut full = base.clone();
            full.extend(p);
            out.insert(full);
        }
    }
    out
}

/// Every path `text` names in crate `krate` (`d3il_server::a::b`, and each
/// leaf of `use d3il_server::{a, b::c}`), as its segments after the crate's
/// name. Comments are skipped; inline test modules are read too, since what
/// they import is part of the file.
pub fn paths_into(text: &str, krate: &str) -> BTreeSet<Vec<String>> {
    let code = text
        .lines()
        .map(|l| l.find("//").map_or(l, |i| &l[..i]))
        .collect::<Vec<_>>()
        .join("\n");
    let needle = format!("{krate}::");
    let mut out = BTreeSet::new();
    for (i, _) in code.match_indices(&needle) {
        let prev = code[..i].chars().next_back();
        if prev.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == '$') {
            continue;
        }
        out.extend(use_tree(&code[i + needle.len()..]));
    }
    out
}

/// The module graph of the crate whose sources are under `src`: one node per
/// file (`a::b`), edges to the modules its paths name.
pub fn crate_graph(src: &Path) -> Graph {
    let files = rust_files(src);
    // Where each file sits in the module tree, `#[path]` attributes included.
    let mut module: BTreeMap<PathBuf, Vec<String>> = BTreeMap::new();
    for f in &files {
        let rel = f.strip_prefix(src).unwrap_or(f);
        if rel.starts_with("bin") {
            continue; // other crate roots
        }
        module.entry(f.clone()).or_insert_with(|| module_of(rel));
    }
    for f in &files {
        let Some(here) = module.get(f).cloned() else {
            continue;
        };
        let text = std::fs::read_to_string(f).unwrap_or_default();
        for (file, name) in path_attributes(&text) {
            let target = f.parent().unwrap_or(src).join(file);
            let mut m = here.clone();
            m.push(name);
            module.insert(target, m);
        }
    }
    let sources: Vec<(Vec<String>, String)> = module
        .iter()
        .map(|(f, m)| (m.clone(), std::fs::read_to_string(f).unwrap_or_default()))
        .collect();
    graph_of(&sources)
}

/// The module graph of files given as (module path, text).
pub fn graph_of(files: &[(Vec<String>, String)]) -> Graph {
    let known: BTreeSet<Vec<String>> = files.iter().map(|(m, _)| m.clone()).collect();
    let mut g = Graph::new();
    for (here, text) in files {
        if here.is_empty() {
            continue;
        }
        let node = here.join("::");
        let edges = g.entry(node).or_default();
        for path in referenced_paths(text, here) {
            let target = (0..=path.len())
                .rev()
                .map(|n| &path[..n])
                .find(|p| known.contains(*p))
                .unwrap_or(&[]);
            if target.is_empty() || target.starts_with(here) {
                continue;
            }
            edges.insert(target.join("::"));
        }
    }
    g
}

/// The cycles of `g`: each strongly connected component of more than one
/// module, as a path through it that returns to its start.
pub fn cycles(g: &Graph) -> Vec<Vec<String>> {
    // Tarjan's algorithm.
    struct S<'a> {
        g: &'a Graph,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on: BTreeSet<&'a str>,
        comps: Vec<Vec<&'a str>>,
    }
    fn visit<'a>(s: &mut S<'a>, n: &'a str) {
        let i = s.index.len();
        s.index.insert(n, i);
        s.low.insert(n, i);
        s.stack.push(n);
        s.on.insert(n);
        for m in s.g.get(n).into_iter().flatten() {
            let m = m.as_str();
            if !s.index.contains_key(m) {
                visit(s, m);
                let l = s.low[m].min(s.low[n]);
                s.low.insert(n, l);
            } else if s.on.contains(m) {
                let l = s.index[m].min(s.low[n]);
                s.low.insert(n, l);
            }
        }
        if s.low[n] == s.index[n] {
            let mut comp = vec![];
            while let Some(m) = s.stack.pop() {
                s.on.remove(m);
                comp.push(m);
                if m == n {
                    break;
                }
            }
            if comp.len() > 1 {
                s.comps.push(comp);
            }
        }
    }
    let mut s = S {
        g,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: vec![],
        on: BTreeSet::new(),
        comps: vec![],
    };
    for n in g.keys() {
        if !s.index.contains_key(n.as_str()) {
            visit(&mut s, n);
        }
    }
    s.comps
        .into_iter()
        .map(|comp| {
            // The shortest way from the component's first module back to it.
            let set: BTreeSet<&str> = comp.iter().copied().collect();
            let start = *comp.iter().min().expect("non-empty");
            let mut came_from: BTreeMap<&str, &str> = BTreeMap::new();
            let mut queue = std::collections::VecDeque::from([start]);
            'search: while let Some(at) = queue.pop_front() {
                for m in g[at].iter().map(String::as_str).filter(|m| set.contains(m)) {
                    if m == start {
                        came_from.insert(start, at);
                        break 'search;
                    }
                    if !came_from.contains_key(m) {
                        came_from.insert(m, at);
                        queue.push_back(m);
                    }
                }
            }
            let mut path = vec![start.to_string()];
            let mut at = came_from[start];
            while at != start {
                path.push(at.to_string());
                at = came_from[at];
            }
            path.push(start.to_string());
            path.reverse();
            path
        })
        .collect()
}

/// Whether module `m` is `root` or one of its submodules.
fn is_under(m: &str, root: &str) -> bool {
    m == root || m.strip_prefix(root).is_some_and(|r| r.starts_with("::"))
}

/// The child of `parent` that module `m` (under `parent`) belongs to:
/// `cmd::submit` for `cmd::submit::race` under `cmd`.
fn member_of<'a>(m: &'a str, parent: &str) -> &'a str {
    let rest = &m[parent.len() + 2..];
    &m[..parent.len() + 2 + rest.find("::").unwrap_or(rest.len())]
}

/// The edges of `g` between the children of `parent` that are to stay
/// apart, as (from, to): from a module under one child of `parent` (the
/// child or its submodules) to another child, or to `parent` itself. A
/// child's references to its own submodules and theirs to it are not
/// counted; what the children share goes outside `parent`.
pub fn sibling_imports(g: &Graph, parent: &str) -> Vec<(String, String)> {
    let mut out = vec![];
    for (from, targets) in g {
        if from == parent || !is_under(from, parent) {
            continue;
        }
        let own = member_of(from, parent);
        for to in targets {
            if to == parent || (is_under(to, parent) && !is_under(to, own)) {
                out.push((from.clone(), to.clone()));
            }
        }
    }
    out
}

/// The edges of `g` from a module under `a` to one under `b`, or from under
/// `b` to under `a`, as (from, to): two parts of a crate that use neither
/// the other.
pub fn imports_between(g: &Graph, a: &str, b: &str) -> Vec<(String, String)> {
    let mut out = vec![];
    for (from, targets) in g {
        for to in targets {
            if (is_under(from, a) && is_under(to, b)) || (is_under(from, b) && is_under(to, a)) {
                out.push((from.clone(), to.clone()));
            }
        }
    }
    out
}
