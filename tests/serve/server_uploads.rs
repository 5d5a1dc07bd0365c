//! Uploads under hostile use (issue 17), against the real `d3il serve`
//! process: a 200 MiB upload is streamed to disk (the server's peak RSS, read
//! from /proc, stays within 100 MB of idle), refused uploads leave no file
//! (over the size cap, over the disk quota, refused before the body is read,
//! invalid after it), a failed submission's file is deleted, and a restart
//! removes temporary files a crash left behind.

use crate::{D3IL, EXE};
use d3il_test_support::server::*;
use serde_json::Value;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::Duration;

const BOUNDARY: &str = "d3ilUploadBoundary0123456789";
const MIB: usize = 1 << 20;

fn policies_dir(db: &Path) -> PathBuf {
    let stem = db.file_stem().unwrap().to_string_lossy().into_owned();
    db.with_file_name(format!("{stem}-data")).join("policies")
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .map(|d| {
            d.flatten()
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// One kB of the upload's filler (never contains the boundary).
fn filler() -> Vec<u8> {
    (0..1024u32).map(|i| (i % 251) as u8).collect()
}

/// A multipart body: the text `fields`, then an `onnx` part of `file_len`
/// filler bytes. Returns (head, tail): the file bytes go between them.
fn multipart(fields: &[(&str, String)]) -> (Vec<u8>, Vec<u8>) {
    let mut head = Vec::new();
    for (k, v) in fields {
        write!(
            head,
            "--{BOUNDARY}\r\nContent-Disposition: form-data; name=\"{k}\"\r\n\r\n{v}\r\n"
        )
        .unwrap();
    }
    write!(
        head,
        "--{BOUNDARY}\r\nContent-Disposition: form-data; name=\"onnx\"; filename=\"p.onnx\"\r\n\
         Content-Type: application/octet-stream\r\n\r\n"
    )
    .unwrap();
    (head, format!("\r\n--{BOUNDARY}--\r\n").into_bytes())
}

/// POSTs the submission over a raw socket, generating the file as it goes
/// (the test holds at most 1 kB of it), while another thread reads the
/// answer: the server may answer and close before the body is sent.
/// `send_file` bytes of the `file_len` declared are sent, then the writer
/// waits for the answer.
fn post_streamed(
    base: &str,
    token: &str,
    fields: &[(&str, String)],
    file_len: usize,
    send_file: usize,
) -> (u16, String) {
    let addr = base.trim_start_matches("http://");
    let mut sock = TcpStream::connect(addr).expect("connect");
    sock.set_read_timeout(Some(Duration::from_secs(120)))
        .unwrap();
    let (head, tail) = multipart(fields);
    let len = head.len() + file_len + tail.len();
    let mut reader = sock.try_clone().unwrap();
    let answer = std::thread::spawn(move || {
        let mut got = Vec::new();
        let mut buf = [0u8; 8192];
        loop {
            match reader.read(&mut buf) {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    got.extend_from_slice(&buf[..n]);
                    if complete(&got) {
                        break;
                    }
                }
            }
        }
        got
    });
    let mut send = || -> std::io::Result<()> {
        write!(
            sock,
            "POST /api/v1/submissions HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {token}\r\n\
             Content-Type: multipart/form-data; boundary={BOUNDARY}\r\nContent-Length: {len}\r\n\
             Connection: close\r\n\r\n"
        )?;
        sock.write_all(&head)?;
        let chunk = filler();
        let mut sent = 0;
        while sent < send_file {
            let n = chunk.len().min(send_file - sent);
            sock.write_all(&chunk[..n])?;
            sent += n;
        }
        if send_file == file_len {
            sock.write_all(&tail)?;
        }
        Ok(())
    };
    // A write error means the server answered and closed early.
    let _ = send();
    let got = answer.join().unwrap();
    let text = String::from_utf8_lossy(&got).into_owned();
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or_else(|| panic!("no HTTP answer: {text:?}"));
    let body = text.split_once("\r\n\r\n").map(|x| x.1).unwrap_or("");
    (status, body.to_string())
}

/// Whether `got` holds a whole response (header and Content-Length body).
fn complete(got: &[u8]) -> bool {
    let text = String::from_utf8_lossy(got);
    let Some((head, body)) = text.split_once("\r\n\r\n") else {
        return false;
    };
    head.lines()
        .find_map(|l| {
            let (k, v) = l.split_once(':')?;
            k.eq_ignore_ascii_case("content-length")
                .then(|| v.trim().parse::<usize>().ok())?
        })
        .is_some_and(|n| body.len() >= n)
}

fn fields(method: &str, seed: u32) -> Vec<(&'static str, String)> {
    vec![
        ("method", method.to_string()),
        ("task", "aligning".into()),
        ("training_seed", seed.to_string()),
        (
            "manifest",
            r#"{"task": "aligning", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#
                .into(),
        ),
    ]
}

/// kB from a `/proc/<pid>/status` line such as `VmHWM:  21000 kB`.
fn proc_kb(pid: u32, key: &str) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).expect("proc status");
    status
        .lines()
        .find_map(|l| l.strip_prefix(key))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap_or_else(|| panic!("no {key} in /proc/{pid}/status"))
}

/// A 200 MiB upload is accepted and stored under its SHA-256 while the
/// server's peak resident memory stays under idle + 100 MB: it is streamed to
/// disk, never buffered.
#[test]
fn a_200_mib_upload_is_streamed_to_disk_in_bounded_memory() {
    let dir = TempDir::new("upload-rss");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "alice");
    let server = D3IL.serve(&db, &["--workers", "0", "--no-upload-dry-run"]);
    let pid = server.pid();
    // Warm up every path a submission takes (pages, API, a small upload).
    assert_eq!(server.get_text_blocking("/").0, 200);
    let (s, body) = post_streamed(&server.base, &token, &fields("Warm", 1), 4096, 4096);
    assert_eq!(s, 201, "{body}");
    std::thread::sleep(Duration::from_millis(300));
    let idle = proc_kb(pid, "VmRSS:");

    let len = 200 * MIB;
    let (s, body) = post_streamed(&server.base, &token, &fields("Big", 2), len, len);
    assert_eq!(s, 201, "{body}");
    let hwm = proc_kb(pid, "VmHWM:");
    eprintln!("server RSS idle {idle} kB, peak during a 200 MiB upload {hwm} kB");
    assert!(
        hwm < idle + 100 * 1024,
        "peak RSS {hwm} kB during a 200 MiB upload, idle {idle} kB"
    );

    let v: Value = serde_json::from_str(&body).unwrap();
    let sha = v["policy"]["sha256"]
        .as_str()
        .expect("sha256 in the answer");
    assert_eq!(v["policy"]["bytes"].as_u64(), Some(len as u64), "{v}");
    let stored = policies_dir(&db).join(format!("{sha}.onnx"));
    assert_eq!(std::fs::metadata(&stored).unwrap().len(), len as u64);
    // The running hash is the hash of what was written.
    let out = std::process::Command::new("sha256sum")
        .arg(&stored)
        .output()
        .unwrap();
    let on_disk = String::from_utf8_lossy(&out.stdout);
    assert!(on_disk.starts_with(sha), "{on_disk} vs {sha}");
    assert!(
        files_in(&policies_dir(&db))
            .iter()
            .all(|f| !f.contains(".tmp")),
        "{:?}",
        files_in(&policies_dir(&db))
    );
}

/// Refused uploads leave no file behind: over the size cap (413), over the
/// submitter's disk quota (413 naming the flag), refused before the body is
/// read (a method of another submitter: 409 while most of the file was never
/// sent), and invalid after the file (400).
#[test]
fn refused_uploads_leave_no_file() {
    let dir = TempDir::new("upload-refused");
    let db = dir.path().join("lb.sqlite");
    let alice = D3IL.create_token(&db, "alice");
    let bob = D3IL.create_token(&db, "bob");
    let server = D3IL.serve(
        &db,
        &[
            "--workers",
            "0",
            "--no-upload-dry-run",
            "--max-upload-mb",
            "8",
            "--max-disk-mb-per-submitter",
            "12",
        ],
    );
    let policies = policies_dir(&db);

    // Over the size cap: refused as it passes 8 MiB, with the flag named.
    let (s, body) = post_streamed(&server.base, &alice, &fields("A", 1), 9 * MIB, 9 * MIB);
    assert_eq!(s, 413, "{body}");
    assert!(body.contains("--max-upload-mb"), "{body}");
    assert_eq!(files_in(&policies), Vec::<String>::new());

    // Within the quota: accepted (7 MiB of 12).
    let (s, body) = post_streamed(&server.base, &alice, &fields("A", 2), 7 * MIB, 7 * MIB);
    assert_eq!(s, 201, "{body}");
    assert_eq!(files_in(&policies).len(), 1);
    // Another 7 MiB would pass the 12 MiB quota.
    let (s, body) = post_streamed(&server.base, &alice, &fields("A", 3), 7 * MIB, 7 * MIB);
    assert_eq!(s, 413, "{body}");
    assert!(body.contains("--max-disk-mb-per-submitter"), "{body}");
    assert!(body.contains("12 MiB"), "{body}");
    assert_eq!(files_in(&policies).len(), 1, "{:?}", files_in(&policies));

    // Bob may not add to Alice's method: refused before the file is read
    // (only 64 kB of the declared 8 MiB is ever sent, and the answer comes).
    let (s, body) = post_streamed(&server.base, &bob, &fields("A", 9), 7 * MIB, 64 << 10);
    assert_eq!(s, 409, "{body}");
    assert!(body.contains("belongs to another submitter"), "{body}");
    // A seed Alice already used: refused before the file too.
    let (s, body) = post_streamed(&server.base, &alice, &fields("A", 2), 7 * MIB, 64 << 10);
    assert_eq!(s, 409, "{body}");

    // Invalid only once the whole body is read (no manifest at all).
    let mut no_manifest = fields("B", 1);
    no_manifest.pop();
    let (s, body) = post_streamed(&server.base, &bob, &no_manifest, MIB, MIB);
    assert_eq!(s, 400, "{body}");
    assert!(body.contains("manifest"), "{body}");
    assert_eq!(files_in(&policies).len(), 1, "{:?}", files_in(&policies));
}

/// A submission that fails deletes its file (keeping the hash), and a
/// restart removes temporary files and unreferenced files a crash left
/// behind while keeping the files of live submissions.
#[test]
fn failed_submissions_and_crash_debris_leave_no_files() {
    let dir = TempDir::new("upload-debris");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "alice");
    let policies = policies_dir(&db);
    let server = D3IL.serve(&db, &["--workers", "1", "--no-upload-dry-run"]);
    // 4 kB of filler is no ONNX model: the real worker fails it.
    let (s, body) = post_streamed(&server.base, &token, &fields("Junk", 1), 4096, 4096);
    assert_eq!(s, 201, "{body}");
    let v: Value = serde_json::from_str(&body).unwrap();
    let id = v["id"].as_i64().unwrap();
    let sha = v["policy"]["sha256"].as_str().unwrap().to_string();
    let client = server.client(None);
    let failed = wait_for(Duration::from_secs(120), || {
        let v = client.get(&format!("/api/v1/submissions/{id}")).ok()?;
        (v["status"] == "failed").then_some(v)
    })
    .expect("the junk submission fails");
    assert_eq!(failed["policy"]["sha256"], sha.as_str(), "{failed}");
    let gone = wait_for(Duration::from_secs(10), || {
        files_in(&policies).is_empty().then_some(())
    });
    assert!(gone.is_some(), "{:?}", files_in(&policies));
    server.kill();

    // A queued submission's file (no worker runs it).
    let server = D3IL.serve(&db, &["--workers", "0", "--no-upload-dry-run"]);
    let (s, body) = post_streamed(&server.base, &token, &fields("Kept", 1), 8192, 8192);
    assert_eq!(s, 201, "{body}");
    let kept = files_in(&policies);
    assert_eq!(kept.len(), 1, "{kept:?}");
    server.kill();

    // Debris of an upload interrupted by a crash, and a stored file no
    // submission refers to (a crash before its submission was recorded).
    let stray = policies.join("upload.onnx.tmp4242-7");
    std::fs::write(&stray, b"half an upload").unwrap();
    let other = policies.join("abc.onnx.tmp1-0");
    std::fs::write(&other, b"half a file").unwrap();
    let orphan = policies.join(format!("{}.onnx", "e".repeat(64)));
    std::fs::write(&orphan, b"nobody's file").unwrap();
    let server = D3IL.serve(&db, &["--workers", "0", "--no-upload-dry-run"]);
    assert_eq!(
        files_in(&policies),
        kept,
        "only the queued submission's file is left"
    );
    assert_eq!(server.get_text_blocking("/").0, 200);
}

/// By default an uploaded model runs a few sandboxed steps of the quick
/// protocol before it is queued: one that cannot run is refused at
/// submission (400 naming the `onnx` field, the worker's reason, no file
/// kept), one that runs is accepted, and the dry run tells whether its
/// evaluation will simulate each initial state once (a deterministic graph)
/// or every rollout (a graph with a `noise` input).
#[test]
fn an_upload_that_cannot_run_is_refused_at_submission() {
    let dir = TempDir::new("upload-dry-run");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "alice");
    let policies = policies_dir(&db);
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let client = server.client(Some(&token));
    let fixtures = d3il_test_support::fixtures_dir();
    let manifest = std::fs::read_to_string(fixtures.join("aligning_mlp.json")).unwrap();
    let form = |method: &str| {
        vec![
            ("method", method.to_string()),
            ("task", "aligning".to_string()),
            ("training_seed", "0".to_string()),
            ("manifest", manifest.clone()),
        ]
    };
    let junk = dir.path().join("junk.onnx");
    std::fs::write(&junk, filler()).unwrap();
    match client.submit(&form("Junk"), Some(&junk)) {
        Err(d3il_server::client::ClientError::Api {
            status,
            field,
            message,
            ..
        }) => {
            assert_eq!(status, 400, "{message}");
            assert_eq!(field.as_deref(), Some("onnx"), "{message}");
            assert!(message.contains("dry run"), "{message}");
            assert!(message.contains("bad_model"), "{message}");
        }
        other => panic!("a junk model was not refused: {other:?}"),
    }
    assert_eq!(files_in(&policies), Vec::<String>::new());
    let created = client
        .submit(&form("Runs"), Some(&fixtures.join("aligning_mlp.onnx")))
        .expect("a model that runs is accepted");
    assert_eq!(created["status"], "queued", "{created}");
    assert_eq!(created["policy"]["simulated_once"], true, "{created}");
    assert_eq!(files_in(&policies).len(), 1);
    let noise = std::fs::read_to_string(fixtures.join("aligning_mlp_noise.json")).unwrap();
    let mut fields = form("Noisy");
    fields[3].1 = noise;
    let created = client
        .submit(&fields, Some(&fixtures.join("aligning_mlp_noise.onnx")))
        .expect("a model with a noise input that runs is accepted");
    assert_eq!(created["policy"]["simulated_once"], false, "{created}");
}

/// A submitter out of quota who uploads a large file with `d3il submit`
/// reads the server's refusal (429 `quota_exceeded`, saying when the next
/// submission is possible), not a broken connection: the server answers
/// before it reads the file and reads the rest of the body on, so its answer
/// is not lost to a reset (server/src/linger.rs). A wrong token likewise.
#[test]
fn a_quota_refusal_reaches_d3il_submit_during_a_large_upload() {
    let dir = TempDir::new("upload-quota");
    let db = dir.path().join("lb.sqlite");
    let token = D3IL.create_token(&db, "alice");
    let server = D3IL.serve(
        &db,
        &[
            "--workers",
            "0",
            "--no-upload-dry-run",
            "--max-upload-mb",
            "64",
            "--quota-per-day",
            "1",
        ],
    );
    // Well past what the socket buffers of 127.0.0.1 absorb (a few MiB):
    // most of it is still to be sent when the refusal comes.
    let onnx = dir.path().join("big.onnx");
    std::fs::write(&onnx, filler().repeat(32 << 10)).unwrap();
    std::fs::write(
        dir.path().join("big.json"),
        r#"{"task": "aligning", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#,
    )
    .unwrap();
    let submit_as = |token: &str, seed: &str| {
        std::process::Command::new(EXE)
            .args(["submit", "--server", &server.base, "--token", token])
            .args([
                "--method",
                "Big",
                "--task",
                "aligning",
                "--protocol",
                "quick",
            ])
            .args(["--training-seed", seed, "--onnx"])
            .arg(&onnx)
            .output()
            .expect("run d3il submit")
    };
    let submit = |seed: &str| submit_as(&token, seed);
    let first = submit("1");
    let err = String::from_utf8_lossy(&first.stderr);
    assert!(first.status.success(), "{err}");
    assert!(
        err.contains("quota: 0 of 1 evaluations left today"),
        "{err}"
    );
    let policies = policies_dir(&db);
    assert_eq!(files_in(&policies).len(), 1);
    for _ in 0..3 {
        let second = submit("2");
        let err = String::from_utf8_lossy(&second.stderr);
        assert!(!second.status.success(), "{err}");
        assert!(
            err.contains("the server refused the request (429, quota_exceeded): daily evaluation quota reached: 1 evaluations in the last 24 hours (limit 1, --quota-per-day) and a plain evaluation counts 1; it is possible in "),
            "{err}"
        );
        assert_eq!(
            files_in(&policies).len(),
            1,
            "the refused upload left no file"
        );
    }
    // Any early answer does the same: a wrong token, refused before the body.
    let wrong = submit_as("d3il_0000000000000000000000000000", "3");
    let err = String::from_utf8_lossy(&wrong.stderr);
    assert!(err.contains("the server refused the request (401"), "{err}");
    // The server still serves.
    assert_eq!(server.get_text_blocking("/healthz").0, 200);
}
