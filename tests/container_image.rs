//! The container image of docs/cluster's Kubernetes manifests (issue 42 item 6):
//! docs/cluster/Containerfile built with podman from a Debian bookworm base made
//! here from Debian's packages (scripts/bookworm_base.sh: mmdebstrap, then
//! `podman import`; no image registry is reachable), tagged with the image the
//! manifests name. The image then runs a quick `d3il eval` that gives the host's
//! result bit for bit, and `d3il serve` in it answers `/healthz` through a
//! published port and computes its fidelity report from the image's data.
//!
//! The base tarball is cached under ~/.cache/d3il/images keyed by the script's
//! sha256 (about 90 s to make), its imported image kept under the same key;
//! podman's layer cache keeps the Containerfile's apt step, so a rerun with a
//! changed binary only copies it and runs the canary (`d3il verify`) again.
//! The podman configuration that runs on these CI machines (root, cgroups v1
//! with a v2 hierarchy beside it, no CAP_SYS_RESOURCE) is in `podman()`
//! (docs/ops.md, Container image).

use d3il_test_support::{assets_dir, repo_dir, TempDir};
use serde_json::Value;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

/// podman with the settings these machines need: runc, since crun refuses a
/// cgroup hierarchy with v1 and v2 controllers mounted at once ("cgroups in
/// hybrid mode not supported"); the limits of [`ulimit_args`] (podman's
/// defaults for run, 1048576 open files and processes, need CAP_SYS_RESOURCE,
/// which these machines do not give).
fn podman() -> Command {
    let mut c = Command::new("podman");
    c.args(["--runtime", "runc"]);
    c
}

/// `--ulimit` for build and run: open files at this process's hard limit at
/// most, processes at podman build's default (32768; with any `--ulimit`
/// given, podman run otherwise asks for 1048576, which fails the same way).
fn ulimit_args() -> [String; 4] {
    let limits = std::fs::read_to_string("/proc/self/limits").unwrap();
    let hard: u64 = limits
        .lines()
        .find(|l| l.starts_with("Max open files"))
        .and_then(|l| l.split_whitespace().nth(4))
        .and_then(|v| v.parse().ok())
        .unwrap_or(1024);
    let n = hard.min(1_048_576);
    [
        "--ulimit".into(),
        format!("nofile={n}:{n}"),
        "--ulimit".into(),
        "nproc=32768:32768".into(),
    ]
}

fn run(cmd: &mut Command, what: &str) -> Output {
    let out = cmd.output().unwrap_or_else(|e| {
        panic!("{what}: {e} (./dev test installs podman, runc and mmdebstrap)")
    });
    d3il_test_support::succeeded(&out, what);
    out
}

/// sha256sum of a file, as ./dev keys the virtualenvs.
fn sha256_hex(path: &Path) -> String {
    let out = run(Command::new("sha256sum").arg(path), "sha256sum");
    String::from_utf8_lossy(&out.stdout)[..64].to_string()
}

/// The imported base image, made (and its tarball cached) when missing.
fn base_image() -> String {
    let script = repo_dir().join("scripts/bookworm_base.sh");
    let key = &sha256_hex(&script)[..16];
    let tag = format!("localhost/d3il-base:bookworm-{key}");
    if podman()
        .args(["image", "exists", &tag])
        .status()
        .unwrap()
        .success()
    {
        return tag;
    }
    let home = std::env::var_os("HOME").expect("HOME");
    let dir = PathBuf::from(home).join(".cache/d3il/images");
    std::fs::create_dir_all(&dir).unwrap();
    let tar = dir.join(format!("bookworm-{key}.tar"));
    if !tar.is_file() {
        let part = dir.join(format!("bookworm-{key}.tar.part-{}", std::process::id()));
        run(Command::new(&script).arg(&part), "scripts/bookworm_base.sh");
        std::fs::rename(&part, &tar).unwrap();
    }
    run(podman().arg("import").arg(&tar).arg(&tag), "podman import");
    tag
}

fn manifest_images() -> (String, String) {
    let cluster = repo_dir().join("docs/cluster");
    let mut images = Vec::new();
    let mut assets = Vec::new();
    for name in ["d3il-indexed-job.yaml", "d3il-merge-job.yaml"] {
        let out = run(
            Command::new("python3")
                .args([
                    "-c",
                    "import json, sys, yaml; json.dump(yaml.safe_load(open(sys.argv[1])), sys.stdout)",
                ])
                .arg(cluster.join(name)),
            "python3 with yaml",
        );
        let job: Value = serde_json::from_slice(&out.stdout).unwrap();
        let c = &job["spec"]["template"]["spec"]["containers"][0];
        images.push(c["image"].as_str().unwrap().to_string());
        assert_eq!(
            c["imagePullPolicy"], "IfNotPresent",
            "{name}: a locally built image"
        );
        for e in c["env"].as_array().into_iter().flatten() {
            if e["name"] == "D3IL_ASSETS" {
                assets.push(e["value"].as_str().unwrap().to_string());
            }
        }
    }
    assert!(images.iter().all(|i| *i == images[0]), "{images:?}");
    assert_eq!(assets.len(), 1);
    (images.remove(0), assets.remove(0))
}

fn copy_dir(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for e in std::fs::read_dir(from).unwrap() {
        let e = e.unwrap();
        let t = to.join(e.file_name());
        if e.file_type().unwrap().is_dir() {
            copy_dir(&e.path(), &t);
        } else {
            std::fs::copy(e.path(), &t).unwrap();
        }
    }
}

/// Removes the container on drop (a failed assertion included).
struct Container(String);

impl Drop for Container {
    fn drop(&mut self) {
        let _ = podman().args(["rm", "-f", "-t", "2", &self.0]).output();
    }
}

/// One HTTP/1.0 GET: the status code and body.
fn get(port: u16, path: &str) -> Option<(u16, String)> {
    let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(10))).ok()?;
    write!(s, "GET {path} HTTP/1.0\r\nHost: 127.0.0.1\r\n\r\n").ok()?;
    let mut text = String::new();
    s.read_to_string(&mut text).ok()?;
    let status = text.split_whitespace().nth(1)?.parse().ok()?;
    let body = text.split_once("\r\n\r\n").map(|(_, b)| b.to_string())?;
    Some((status, body))
}

fn without_timing(path: &Path) -> Value {
    let mut v: Value = serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap();
    v["metrics"]["inference_ms"] = Value::Null;
    v
}

#[test]
fn containerfile_builds_the_manifests_image_which_evaluates_and_serves() {
    let (image, assets_in_image) = manifest_images();
    let base = base_image();

    // The build context of the Containerfile's header: the binary, assets/
    // and the reference data.
    let tmp = TempDir::new("container");
    let ctx = tmp.path().join("ctx");
    std::fs::create_dir_all(&ctx).unwrap();
    std::fs::copy(env!("CARGO_BIN_EXE_d3il"), ctx.join("d3il")).unwrap();
    copy_dir(&assets_dir(), &ctx.join("assets"));
    for d in [
        "reference-rollouts",
        "reference-closed-loop",
        "reference-frames",
    ] {
        copy_dir(
            &repo_dir().join("tests/data").join(d),
            &ctx.join("reference").join(d),
        );
    }
    let image_id = || {
        let out = podman()
            .args(["image", "inspect", "--format", "{{.Id}}", &image])
            .output()
            .unwrap();
        out.status
            .success()
            .then(|| String::from_utf8_lossy(&out.stdout).trim().to_string())
    };
    let before = image_id();
    let t = Instant::now();
    run(
        podman()
            .arg("build")
            .args(ulimit_args())
            .args(["--build-arg", &format!("BASE={base}"), "-t", &image, "-f"])
            .arg(repo_dir().join("docs/cluster/Containerfile"))
            .arg(&ctx),
        "podman build",
    );
    eprintln!("podman build: {:.0} s", t.elapsed().as_secs_f64());
    // The previous build's image (untagged now) goes; its base and apt
    // layers stay, shared with this one.
    if let Some(old) = before.filter(|old| Some(old) != image_id().as_ref()) {
        let _ = podman().args(["rmi", &old]).output();
    }

    let inspect = run(
        podman().args([
            "image",
            "inspect",
            "--format",
            "{{json .Config.Env}}",
            &image,
        ]),
        "podman image inspect",
    );
    let env: Vec<String> = serde_json::from_slice(&inspect.stdout).unwrap();
    assert!(
        env.contains(&format!("D3IL_ASSETS={assets_in_image}")),
        "the manifests' D3IL_ASSETS is not the image's: {env:?}"
    );
    let mujoco = run(
        podman().args(["run", "--rm"]).args(ulimit_args()).args([
            &image,
            "dpkg-query",
            "-W",
            "-f",
            "${Version}",
            "libmujoco2.2.2",
        ]),
        "dpkg-query in the image",
    );
    assert!(String::from_utf8_lossy(&mujoco.stdout).starts_with("2.2.2"));

    // A quick evaluation in the image gives the host's result bit for bit
    // (the same binary, hence the same physics fingerprint in the manifest).
    let out = tmp.path().join("out");
    std::fs::create_dir_all(&out).unwrap();
    let eval = [
        "d3il",
        "eval",
        "--task",
        "avoiding",
        "--policy",
        "scripted:avoiding:all-paths",
        "--protocol",
        "quick",
        "--seed",
        "3",
        "--json",
    ];
    let inside = run(
        podman()
            .args(["run", "--rm"])
            .args(ulimit_args())
            .arg("-v")
            .arg(format!("{}:/results", out.display()))
            .arg(&image)
            .args(eval)
            .arg("/results/result.json"),
        "d3il eval in the image",
    );
    let stderr = String::from_utf8_lossy(&inside.stderr);
    assert!(
        !stderr.contains("computing this build's physics fingerprint"),
        "the image should hold the fingerprint its build computed: {stderr}"
    );
    run(
        Command::new(env!("CARGO_BIN_EXE_d3il"))
            .args(&eval[1..])
            .arg(tmp.path().join("host.json"))
            .env("D3IL_ASSETS", assets_dir()),
        "d3il eval on the host",
    );
    let (a, b) = (
        without_timing(&out.join("result.json")),
        without_timing(&tmp.path().join("host.json")),
    );
    assert_eq!(a["rollouts"].as_array().unwrap().len(), 8);
    assert!(a["manifest"]["build"]["physics_fingerprint"].is_string());
    assert_eq!(a, b);

    // The image's default command serves the leaderboard; /healthz answers
    // through a published port.
    let probe = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = probe.local_addr().unwrap().port();
    drop(probe);
    let name = format!("d3il-image-test-{}", std::process::id());
    run(
        podman()
            .args(["run", "-d", "--name", &name])
            .args(ulimit_args())
            .args(["-p", &format!("127.0.0.1:{port}:8080"), &image]),
        "podman run (d3il serve)",
    );
    let container = Container(name);
    let deadline = Instant::now() + Duration::from_secs(120);
    let mut last = None;
    while Instant::now() < deadline {
        last = get(port, "/healthz");
        if matches!(last, Some((200, _))) {
            break;
        }
        std::thread::sleep(Duration::from_millis(500));
    }
    let logs = podman().args(["logs", &container.0]).output().unwrap();
    assert!(
        matches!(last, Some((200, _))),
        "no 200 from /healthz in the container: {last:?}\n{}",
        String::from_utf8_lossy(&logs.stderr)
    );
    let (status, home) = get(port, "/").unwrap();
    assert_eq!(status, 200);
    assert!(home.contains("D3IL"), "{home}");
    // The fidelity report finds its reference data in the image (a missing
    // directory fails it within a second of the start).
    std::thread::sleep(Duration::from_secs(5));
    let (status, page) = get(port, "/fidelity").unwrap();
    assert_eq!(status, 200);
    assert!(
        page.contains("being computed") && !page.contains("id=\"fidelity-failed\""),
        "{page}"
    );
}
