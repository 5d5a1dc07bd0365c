//! The rollout video pool (issue 31) on a real server: renders run one at a
//! time with a pool of one, concurrent requests for one video share its
//! render, a cached video starts no render, a failing replay is a clear 422
//! (JSON from the API, an HTML page from the site), and videos are served
//! with byte ranges. The renderer here is a shell script taking `d3il
//! replay`'s arguments (`--result DOC --rollout N --video OUT`); the real
//! binary is tested end to end in the root crate (tests/rollout_videos_e2e.rs).

use crate::rollout_support;

use d3il_test_support::server::*;
use rollout_support::*;
use std::path::{Path, PathBuf};

/// Bytes the script writes as the "video" (N.B. not an MP4: the pool does
/// not look inside).
const VIDEO_BYTES: usize = 5000;

/// A renderer that logs `start N` / `end N`, keeps the document it was
/// given, takes `seconds`, and refuses rollout 7 as `d3il replay` refuses
/// a record that does not replay.
fn script(dir: &Path, seconds: &str) -> PathBuf {
    let log = dir.join("renders");
    std::fs::create_dir_all(&log).unwrap();
    let path = dir.join("fake-replay.sh");
    let text = format!(
        r#"#!/bin/sh
set -e
while [ $# -gt 0 ]; do
  case "$1" in
    --result) doc="$2"; shift 2;;
    --rollout) n="$2"; shift 2;;
    --video) out="$2"; shift 2;;
    *) echo "Error: unexpected argument $1" >&2; exit 2;;
  esac
done
echo "start $n" >> {log}/events
cp "$doc" {log}/doc-$n.json
sleep {seconds}
if [ "$n" = 7 ]; then
  echo "Error: rollout 7 does not replay: the state after step 17 differs from the record (digest 0000002a, recorded 00000011)" >&2
  exit 3
fi
head -c {VIDEO_BYTES} /dev/zero | tr '\0' 'v' > "$out"
echo "end $n" >> {log}/events
"#,
        log = log.display()
    );
    std::fs::write(&path, text).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&path, std::fs::Permissions::from_mode(0o755)).unwrap();
    path
}

fn events(dir: &Path) -> Vec<String> {
    std::fs::read_to_string(dir.join("renders/events"))
        .unwrap_or_default()
        .lines()
        .map(String::from)
        .collect()
}

async fn app_with_script(seconds: &str) -> (TestServer, tempfile::TempDir) {
    let scripts = tempfile::tempdir().unwrap();
    let app = spawn_app_with(Options {
        video_exe: Some(script(scripts.path(), seconds)),
        video_renders: 1,
        ..Options::default()
    })
    .await;
    (app, scripts)
}

#[tokio::test]
async fn one_render_slot_renders_one_video_at_a_time() {
    let (app, scripts) = app_with_script("1").await;
    let id = finished_submission(&app.state().store, "Tracer", &traced_result(false)).await;
    let get = |n: usize| {
        app.http
            .get(app.url(&format!("/api/v1/submissions/{id}/rollouts/{n}/video")))
            .send()
    };
    let (a, b) = tokio::join!(get(1), get(2));
    for r in [a.unwrap(), b.unwrap()] {
        assert_eq!(r.status(), 200);
        assert_eq!(r.headers()["content-type"], "video/mp4");
        assert_eq!(r.bytes().await.unwrap().len(), VIDEO_BYTES);
    }
    // With one slot the second render starts after the first ended.
    let ev = events(scripts.path());
    assert_eq!(ev.len(), 4, "{ev:?}");
    assert!(
        ev[0].starts_with("start") && ev[1].starts_with("end"),
        "{ev:?}"
    );
    assert_eq!(
        ev[0][6..],
        ev[1][4..],
        "the first render ends before the next starts: {ev:?}"
    );
    assert!(
        ev[2].starts_with("start") && ev[3].starts_with("end"),
        "{ev:?}"
    );
    assert_eq!(app.state().videos.renders_started(), 2);
    // What the replay was given: the manifest and the one record with its trace.
    let doc: serde_json::Value =
        serde_json::from_slice(&std::fs::read(scripts.path().join("renders/doc-2.json")).unwrap())
            .unwrap();
    assert_eq!(doc["manifest"]["task"], "pushing");
    let recs = doc["rollouts"].as_array().unwrap();
    assert_eq!(recs.len(), 1);
    assert_eq!(
        (
            recs[0]["context_index"].as_u64(),
            recs[0]["rollout_index"].as_u64()
        ),
        (Some(0), Some(2))
    );
    assert!(recs[0]["trace"]["actions"].is_string());
}

#[tokio::test]
async fn two_render_slots_render_two_videos_at_once() {
    let scripts = tempfile::tempdir().unwrap();
    let app = spawn_app_with(Options {
        video_exe: Some(script(scripts.path(), "1")),
        video_renders: 2,
        ..Options::default()
    })
    .await;
    let id = finished_submission(&app.state().store, "Tracer", &traced_result(false)).await;
    let get = |n: usize| {
        app.http
            .get(app.url(&format!("/api/v1/submissions/{id}/rollouts/{n}/video")))
            .send()
    };
    let (a, b) = tokio::join!(get(1), get(2));
    assert_eq!(
        (a.unwrap().status().as_u16(), b.unwrap().status().as_u16()),
        (200, 200)
    );
    // The control of the test above: these requests do overlap.
    let ev = events(scripts.path());
    assert!(
        ev[0].starts_with("start") && ev[1].starts_with("start"),
        "{ev:?}"
    );
}

#[tokio::test]
async fn one_video_asked_twice_is_rendered_once_and_then_cached() {
    let (app, scripts) = app_with_script("1").await;
    let id = finished_submission(&app.state().store, "Tracer", &traced_result(false)).await;
    let url = app.url(&format!("/api/v1/submissions/{id}/rollouts/3/video"));
    let (a, b) = tokio::join!(app.http.get(&url).send(), app.http.get(&url).send());
    assert_eq!(a.unwrap().status(), 200);
    assert_eq!(b.unwrap().status(), 200);
    assert_eq!(
        app.state().videos.renders_started(),
        1,
        "{:?}",
        events(scripts.path())
    );
    // Cached under <submission>-<N>-<version>-<scene>.mp4: no render again,
    // also from the page's route.
    let cached = app
        .state()
        .videos
        .dir()
        .join(format!("{id}-3-{}-m.mp4", env!("CARGO_PKG_VERSION")));
    assert!(cached.is_file(), "{}", cached.display());
    let r = app.http.get(&url).send().await.unwrap();
    assert_eq!(r.status(), 200);
    let r = app
        .http
        .get(app.url(&format!("/submissions/{id}/rollouts/3/video")))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.bytes().await.unwrap().len(), VIDEO_BYTES);
    assert_eq!(app.state().videos.renders_started(), 1);
    // No temporary files are left.
    let names: Vec<String> = std::fs::read_dir(app.state().videos.dir())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(
        names,
        [format!("{id}-3-{}-m.mp4", env!("CARGO_PKG_VERSION"))]
    );
}

#[tokio::test]
async fn a_range_request_gets_206_and_those_bytes() {
    let (app, _scripts) = app_with_script("0").await;
    let id = finished_submission(&app.state().store, "Tracer", &traced_result(false)).await;
    let url = app.url(&format!("/api/v1/submissions/{id}/rollouts/5/video"));
    let r = app
        .http
        .get(&url)
        .header("Range", "bytes=0-99")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 206);
    assert_eq!(r.headers()["content-type"], "video/mp4");
    assert_eq!(
        r.headers()["content-range"],
        format!("bytes 0-99/{VIDEO_BYTES}")
    );
    assert_eq!(r.bytes().await.unwrap().len(), 100);
    let r = app
        .http
        .get(&url)
        .header("Range", "bytes=4990-")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 206);
    assert_eq!(r.bytes().await.unwrap().len(), 10);
    let r = app
        .http
        .get(&url)
        .header("Range", "bytes=9000-")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 416);
    assert_eq!(
        r.headers()["content-range"],
        format!("bytes */{VIDEO_BYTES}")
    );
    let r = app.http.get(&url).send().await.unwrap();
    assert_eq!(r.status(), 200);
    assert_eq!(r.headers()["accept-ranges"], "bytes");
    let tag = r.headers()["etag"].clone();
    assert_eq!(r.bytes().await.unwrap().len(), VIDEO_BYTES);
    let r = app
        .http
        .get(&url)
        .header("If-None-Match", tag)
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 304);
}

#[tokio::test]
async fn a_record_that_does_not_replay_is_a_clear_error() {
    let (app, _scripts) = app_with_script("0").await;
    let id = finished_submission(&app.state().store, "Tracer", &traced_result(false)).await;
    let (s, v) = app
        .get_json(&format!("/api/v1/submissions/{id}/rollouts/7/video"))
        .await;
    assert_eq!(s, 422, "{v}");
    assert_eq!(v["error"]["code"], "not_rendered");
    let m = v["error"]["message"].as_str().unwrap();
    assert!(m.contains("rollout 7 of submission"), "{m}");
    assert!(
        m.contains("does not replay: the state after step 17 differs"),
        "{m}"
    );
    assert!(!m.contains("Error:"), "{m}");
    // The page's route answers with an error page saying the same.
    let (s, page) = app
        .get_text(&format!("/submissions/{id}/rollouts/7/video"))
        .await;
    assert_eq!(s, 422);
    assert!(
        page.contains("<html") && page.contains("after step 17 differs"),
        "{page}"
    );
    // A failure is not cached: asking again replays again.
    assert_eq!(app.state().videos.renders_started(), 2);
    // Nothing was left behind.
    assert_eq!(
        std::fs::read_dir(app.state().videos.dir()).unwrap().count(),
        0
    );
}

#[tokio::test]
async fn a_renderer_that_cannot_start_is_our_fault_not_the_viewers() {
    let app = spawn_app_with(Options {
        video_exe: Some(PathBuf::from("/nonexistent/d3il")),
        ..Options::default()
    })
    .await;
    let id = finished_submission(&app.state().store, "Tracer", &traced_result(false)).await;
    let (s, v) = app
        .get_json(&format!("/api/v1/submissions/{id}/rollouts/1/video"))
        .await;
    assert_eq!(
        (s, v["error"]["code"].as_str()),
        (500, Some("internal")),
        "{v}"
    );
}
