//! Writes the seed inputs of every fuzz target, built from the project's
//! own fixtures, into `<dir>/<target>/` (scripts/fuzz runs it into
//! fuzz/seeds; the fuzzer's corpus, fuzz/corpus, grows from them):
//!
//! ```text
//! cargo run -p d3il-fuzz-targets --example seeds -- fuzz/seeds
//! ```

use d3il_evaluator::tasks::task_def;
use d3il_fuzz_targets::{form, valid_replies};
use d3il_protocol::TaskId;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn read(rel: &str) -> Vec<u8> {
    std::fs::read(repo().join(rel)).unwrap_or_else(|e| panic!("reading {rel}: {e}"))
}

fn json_of(rel: &str) -> Value {
    serde_json::from_slice(&read(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

struct Out(PathBuf);

impl Out {
    fn put(&self, target: &str, name: &str, bytes: &[u8]) {
        let dir = self.0.join(target);
        std::fs::create_dir_all(&dir).expect("seed directory");
        std::fs::write(dir.join(name), bytes).expect("seed file");
    }
}

fn with_byte(b: u8, rest: &[u8]) -> Vec<u8> {
    let mut v = vec![b];
    v.extend_from_slice(rest);
    v
}

fn task_index(t: TaskId) -> u8 {
    TaskId::ALL.iter().position(|x| *x == t).expect("a task") as u8
}

/// The first context of `task`'s committed set in use.
fn first_context(task: TaskId) -> Value {
    let set = task_def(task).expect("task").context_set().expect("set");
    set.get(0).cloned().expect("a context")
}

fn manifests(out: &Out) {
    for f in [
        "aligning_mlp",
        "avoiding_k5_h3",
        "avoiding_noise",
        "aligning_image",
        "aligning_image_k2_h4",
        "hostile_wrong_obs_dim",
        "agents/beso",
        "agents/ddpm_transformer",
    ] {
        out.put(
            "manifest",
            &f.replace('/', "-"),
            &read(&format!("assets/fixtures/{f}.json")),
        );
    }
    out.put(
        "manifest",
        "grow-normalised",
        br#"{"task": "pushing", "obs_type": "state", "history": 3, "horizon": 4, "execute": 2, "window": "grow",
            "normalisation": {"obs_mean": [0, 0, 0, 0, 0, 0, 0, 0, 0, 0], "obs_std": [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]}}"#,
    );
}

fn contexts(out: &Out) {
    for task in TaskId::ALL {
        let def = task_def(task).expect("task");
        for set in def.context_sets().expect("sets") {
            let mut file = serde_json::to_value(&set.file).expect("serialises");
            let few: Vec<Value> = set.file.contexts.iter().take(2).cloned().collect();
            file["contexts"] = Value::Array(few.clone());
            let bytes = serde_json::to_vec_pretty(&file).expect("json");
            out.put("contexts", &set.name, &with_byte(0, &bytes));
            let reference = json!({"source": format!("{} (first two)", set.name), "contexts": few});
            let bytes = serde_json::to_vec(&reference).expect("json");
            out.put(
                "contexts",
                &format!("reference-{}", set.name),
                &with_byte(task_index(task), &bytes),
            );
        }
    }
}

fn replay(out: &Out) {
    for task in TaskId::ALL {
        let act = task_def(task).expect("task").act_dim();
        let episode =
            json!({"context": first_context(task), "actions": vec![vec![0.0f32; act]; 3]});
        let bytes = serde_json::to_vec(&episode).expect("json");
        out.put(
            "replay",
            &format!("episode-{task}"),
            &with_byte(task_index(task), &bytes),
        );
    }
    // One recorded rollout of `d3il eval --protocol quick --json` (Avoiding,
    // scripted paths), replayed as `d3il replay --result F --rollout 0`.
    let mut doc = json_of("fuzz-targets/data/avoiding-quick-result.json");
    let first = doc["rollouts"][0].clone();
    let doc = json!({"manifest": doc["manifest"].take(), "rollouts": [first]});
    let bytes = serde_json::to_vec(&doc).expect("json");
    out.put("replay", "record-avoiding-0", &with_byte(128, &bytes));
}

fn merge(out: &Out) {
    let one = read("fuzz-targets/data/aligning-quick-part-1of2.json");
    let two = read("fuzz-targets/data/aligning-quick-part-2of2.json");
    let mut both = one.clone();
    both.push(0);
    both.extend_from_slice(&two);
    out.put("merge", "aligning-both", &both);
    out.put("merge", "aligning-first-only", &one);
}

fn upload(out: &Out) {
    let api = b"api multipart/form-data; boundary=d3ilfuzz\n".to_vec();
    let manifest =
        r#"{"task": "aligning", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#;
    let onnx = read("assets/fixtures/hostile_wrong_act_dim.onnx");
    let fields = [
        ("method", "Fuzzed MLP"),
        ("task", "aligning"),
        ("training_seed", "3"),
        ("data_fraction", "0.5"),
        ("manifest", manifest),
    ];
    let cases: Vec<(&str, Vec<u8>)> = vec![
        ("onnx", form(&fields, Some(&onnx))),
        (
            "endpoint",
            form(
                &[
                    ("method", "Remote"),
                    ("task", "pushing"),
                    ("training_seed", "1"),
                    ("history", "2"),
                    ("endpoint_url", "ws://93.184.216.34:8765/policy"),
                ],
                None,
            ),
        ),
        (
            "bad-fields",
            form(
                &[
                    ("method", "x/y"),
                    ("task", "sorting-9"),
                    ("obs_type", "image"),
                    ("training_seed", "-1"),
                    ("paper_url", "ftp://x"),
                ],
                None,
            ),
        ),
        ("no-policy", form(&fields, None)),
    ];
    for (name, body) in &cases {
        let mut v = api.clone();
        v.extend_from_slice(body);
        out.put("upload", &format!("api-{name}"), &v);
    }
    let mut cut = b"api-cut multipart/form-data; boundary=d3ilfuzz\n".to_vec();
    cut.extend_from_slice(&cases[0].1[..cases[0].1.len() / 2]);
    out.put("upload", "api-cut-mid-file", &cut);
    let mut page = b"form multipart/form-data; boundary=d3ilfuzz\n".to_vec();
    let mut with_token = vec![("token", "@TOKEN@")];
    with_token.extend_from_slice(&fields[..2]);
    with_token.push(("training_seed", "4"));
    with_token.extend_from_slice(&fields[3..]);
    page.extend_from_slice(&form(&with_token, Some(&onnx)));
    out.put("upload", "form-onnx", &page);
    out.put(
        "upload",
        "api-not-multipart",
        b"api application/json\n{\"method\": \"x\"}",
    );
}

fn api_query(out: &Out) {
    // (route index in api::ROUTES, rest)
    let cases: &[(u8, &str)] = &[
        (0, "aligning?obs=image&view=data-fraction"),
        (
            1,
            "?task=aligning&status=completed&method=Seed&submitter=fuzzer",
        ),
        (
            2,
            "?outcome=success&behaviour=1-2-3&context=0&page=2&per_page=5",
        ),
        (3, "7"),
        (4, "?a=1&b=1"),
        (6, "1/results"),
        (8, "stacking?obs=image&sort=success&dir=asc"),
        (9, "?task=avoiding&status=queued"),
        (11, "3"),
        (12, "?a=1&b=2"),
        (13, "Seed"),
        (14, "?obs=state"),
        (15, "pushing/pareto.svg?obs=state"),
        (16, "paths.svg"),
    ];
    for (i, (route, rest)) in cases.iter().enumerate() {
        out.put(
            "api_query",
            &format!("q{i:02}"),
            &with_byte(*route, rest.as_bytes()),
        );
    }
}

fn remote(out: &Out) {
    for (stage, (name, bytes)) in valid_replies().into_iter().enumerate() {
        out.put("remote_frame", name, &with_byte(stage as u8, &bytes));
        // The same reply as raw socket bytes: one unmasked binary frame.
        let mut frame = vec![0x82];
        match u16::try_from(bytes.len()) {
            Ok(n) if n < 126 => frame.push(n as u8),
            Ok(n) => {
                frame.push(126);
                frame.extend_from_slice(&n.to_be_bytes());
            }
            Err(_) => continue,
        }
        frame.extend_from_slice(&bytes);
        out.put(
            "remote_frame",
            &format!("{name}-raw"),
            &with_byte(0x80 | stage as u8, &frame),
        );
    }
}

fn onnx(out: &Out) {
    // (fixture, index of its manifest in onnx::MANIFESTS)
    for (f, m) in [
        ("avoiding_path", 5),
        ("avoiding_k5_h3", 1),
        ("avoiding_noise", 2),
        ("aligning_image", 3),
        ("aligning_image_k2_h4", 4),
        ("hostile_wrong_act_dim", 5),
        ("hostile_nan", 5),
        ("hostile_mixes_rows", 5),
        ("hostile_random_op", 5),
        ("hostile_huge_initializer", 5),
        ("hostile_external_data", 5),
        ("hostile_tile_bomb", 5),
        ("hostile_truncated", 5),
    ] {
        out.put(
            "onnx_admit",
            f,
            &with_byte(m, &read(&format!("assets/fixtures/{f}.onnx"))),
        );
    }
}

fn main() {
    let dir = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "fuzz/seeds".into());
    let out = Out(PathBuf::from(dir));
    manifests(&out);
    contexts(&out);
    replay(&out);
    merge(&out);
    upload(&out);
    api_query(&out);
    remote(&out);
    onnx(&out);
    println!("seeds written to {}", out.0.display());
}
