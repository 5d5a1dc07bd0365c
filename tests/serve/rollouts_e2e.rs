//! Issue 31 end to end with the real binary: a real `d3il eval` (Aligning's
//! scripted expert, quick protocol) is stored, `d3il serve` lists its
//! rollouts, serves a record that `d3il replay --result` replays, and makes
//! a rollout's video by running `d3il replay --video` (H.264 MP4, one frame
//! per environment state at 200/7 fps: (steps + 1) × 35 ms), caches it and
//! serves byte ranges; an edited record is a 422 naming the step that
//! differs, never a crash.

use crate::rollouts_support;

use crate::D3IL;
use d3il_test_support::server::TempDir;
use rollouts_support::*;
use std::process::Command;

#[test]
fn a_stored_rollout_replays_into_a_video_through_the_server() {
    let dir = TempDir::new("rollouts-e2e");
    let result = eval(dir.path(), "aligning", "scripted:aligning:both");
    assert!(
        result.rollouts.iter().all(|r| r.ending.is_some()),
        "the evaluator records endings"
    );
    let broken = nudged(&result, 1, 5);
    let db = dir.path().join("lb.sqlite");
    let ids = store_finished(&db, &[("Expert", &result), ("Edited", &broken)]);
    let (id, bad) = (ids[0], ids[1]);
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let get = |path: &str| http_get(&server.base, path, &[]);

    // The list: every rollout with its ending and a trace.
    let list = get(&format!("/api/v1/submissions/{id}/rollouts")).json();
    assert_eq!(list["all"].as_u64(), Some(result.rollouts.len() as u64));
    let items = list["items"].as_array().unwrap();
    assert!(
        items
            .iter()
            .all(|i| i["has_trace"] == true && !i["ending"].is_null()),
        "{list}"
    );

    // The record, saved to a file, replays with the real CLI.
    let n = 1;
    let record = get(&format!("/api/v1/submissions/{id}/rollouts/{n}")).body;
    let file = dir.path().join("record.json");
    std::fs::write(&file, &record).unwrap();
    let out = Command::new(EXE)
        .args(["replay", "--result"])
        .arg(&file)
        .args(["--rollout", &n.to_string()])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "the API's record replays: {}",
        String::from_utf8_lossy(&out.stderr)
    );

    // The video: made by `d3il replay --video` in the server's render pool.
    let r = get(&format!("/api/v1/submissions/{id}/rollouts/{n}/video"));
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.header("content-type"), Some("video/mp4"));
    let bytes = r.body;
    assert_eq!(&bytes[4..8], b"ftyp", "an MP4");
    let mp4 = dir.path().join("fetched.mp4");
    std::fs::write(&mp4, &bytes).unwrap();
    let steps = result.rollout(n).unwrap().steps;
    let want = (steps + 1) as f64 * 0.035;
    let got = duration_seconds(&mp4);
    assert!(
        (got - want).abs() <= 0.05 * want,
        "{got} s for {steps} steps, want {want} s"
    );
    // Cached in the data directory next to the policies; asked again, the
    // same file (the server's own cache test counts renders).
    let videos = dir.path().join("lb-data/videos");
    let cached: Vec<_> = std::fs::read_dir(&videos)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(cached.len(), 1, "{cached:?}");
    assert!(cached[0].starts_with(&format!("{id}-{n}-")) && cached[0].ends_with(".mp4"));
    let again = get(&format!("/submissions/{id}/rollouts/{n}/video")).body;
    assert_eq!(again, bytes);
    // A byte range.
    let r = http_get(
        &server.base,
        &format!("/api/v1/submissions/{id}/rollouts/{n}/video"),
        &[("Range", "bytes=0-99")],
    );
    assert_eq!(r.status, 206);
    let range = format!("bytes 0-99/{}", bytes.len());
    assert_eq!(r.header("content-range"), Some(range.as_str()));
    assert_eq!(r.body, bytes[..100]);

    // An edited record does not replay: a clear 422 naming the step, from
    // the API as JSON and from the page's route as a page.
    let r = get(&format!("/api/v1/submissions/{bad}/rollouts/1/video"));
    assert_eq!(r.status, 422);
    let v = r.json();
    assert_eq!(v["error"]["code"], "not_rendered");
    let m = v["error"]["message"].as_str().unwrap();
    assert!(m.contains("after step 6"), "{m}");
    let r = get(&format!("/submissions/{bad}/rollouts/1/video"));
    assert_eq!(r.status, 422);
    assert!(r.text().contains("after step 6"));
    // The server is still there, and the other rollouts still replay.
    let r = get(&format!("/api/v1/submissions/{bad}/rollouts/0/video"));
    assert_eq!(r.status, 200);
    server.kill();
}
