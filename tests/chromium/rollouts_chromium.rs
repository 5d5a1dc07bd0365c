//! Headless Chromium on the rollout views of a real evaluation (issue 31),
//! served by the real `d3il serve`: the rollout page's video plays (its
//! duration is the rollout's (steps + 1) × 35 ms: one frame per environment
//! state, real time), the top-down picture holds the TCP's path, and the
//! submission page's filters narrow its list of rollouts.

use crate::rollouts_support;

use crate::D3IL;
use d3il_test_support::chromium::{chromium, dump_dom, serve_with_script};
use d3il_test_support::server::TempDir;
use rollouts_support::*;

/// Rows of the failure browser in a DOM.
fn rollout_rows(dom: &str) -> usize {
    let table = &dom[dom
        .find("id=\"rollouts-table\"")
        .expect("the rollouts table")..];
    let table = &table[..table.find("</table>").expect("table end")];
    table.matches("class=\"rollout-row\"").count()
}

#[test]
fn chromium_plays_a_rollout_video_and_filters_rollouts() {
    let browser = chromium();
    let dir = TempDir::new("rollouts-chromium");
    let result = eval(dir.path(), "aligning", "scripted:aligning:both");
    let db = dir.path().join("lb.sqlite");
    let id = store_finished(&db, &[("Expert", &result)])[0];
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let n = 3;
    let steps = result.rollout(n).expect("rollout 3").steps;

    // Made once before the browser asks (rendering takes real time).
    let warm = http_get(
        &server.base,
        &format!("/submissions/{id}/rollouts/{n}/video"),
        &[],
    );
    assert_eq!(warm.status, 200, "{}", warm.text());

    // The rollout page, with a script (the site runs none) that plays the
    // video and writes what the browser saw into the DOM.
    let page = http_get(
        &server.base,
        &format!("/submissions/{id}/rollouts/{n}"),
        &[],
    );
    assert_eq!(page.status, 200);
    let script = "<script>window.addEventListener('load', function () {\
        var v = document.querySelector('#video video');\
        var out = document.createElement('pre'); out.id = 'video-report';\
        function report(t) { out.textContent = t; document.body.appendChild(out); }\
        v.muted = true;\
        v.addEventListener('error', function () { report('error ' + (v.error ? v.error.code + ' ' + v.error.message : '?') + ' end'); });\
        v.play().then(function () {\
          (function check() {\
            if (v.readyState >= 3) { report('played ' + v.readyState + ' ' + v.duration + ' end'); }\
            else { setTimeout(check, 50); }\
          })();\
        }, function (e) { report('play refused ' + e + ' end'); });\
        });</script>";
    let url = serve_with_script(&page.text(), &server.base, script);
    let dom = dump_dom(
        &browser,
        &url,
        &dir.path().join("profile-video"),
        &[
            "--autoplay-policy=no-user-gesture-required",
            "--mute-audio",
            "--virtual-time-budget=15000",
        ],
    );
    let report = dom
        .split("<pre id=\"video-report\">")
        .nth(1)
        .and_then(|r| r.split(" end").next())
        .unwrap_or_else(|| panic!("no video report in the DOM:\n{dom}"));
    eprintln!("video report: {report}; steps {steps}");
    let words: Vec<&str> = report.split(' ').collect();
    assert_eq!(words[0], "played", "{report}");
    let ready: u32 = words[1].parse().unwrap();
    assert!(ready >= 3, "readyState {ready}");
    let duration: f64 = words[2].parse().unwrap();
    let want = (steps + 1) as f64 * 0.035;
    assert!(
        (duration - want).abs() <= 0.05 * want,
        "video of {steps} steps lasts {duration} s, want {want} s"
    );
    // The top-down picture holds the TCP's path.
    let fig = &dom[dom.find("id=\"top-down\"").expect("the top-down figure")..];
    let fig = &fig[..fig.find("</figure>").expect("figure end")];
    assert!(fig.contains("<svg"), "inline SVG");
    let path = &fig[fig.find("class=\"tcp-path").expect("g.tcp-path")..];
    assert!(
        path.contains("<polyline") || path.contains("<path"),
        "{path:.400}"
    );

    // The submission page: the filters narrow the list.
    let profile = dir.path().join("profile-pages");
    let all = dump_dom(
        &browser,
        &format!("{}/submissions/{id}", server.base),
        &profile,
        &[],
    );
    let total = result.rollouts.len();
    assert_eq!(rollout_rows(&all), total);
    assert!(all.contains("id=\"rollout-filters\""));
    let by_state = dump_dom(
        &browser,
        &format!("{}/submissions/{id}?context=1#rollouts", server.base),
        &profile,
        &[],
    );
    let per = result.manifest.rollouts_per_context;
    assert_eq!(rollout_rows(&by_state), per);
    assert!(per < total);
    let label = d3il_protocol::behaviour_name(result.manifest.task, &result.rollouts[0].behaviour);
    let same = result
        .rollouts
        .iter()
        .filter(|r| d3il_protocol::behaviour_name(result.manifest.task, &r.behaviour) == label)
        .count();
    let by_behaviour = dump_dom(
        &browser,
        &format!(
            "{}/submissions/{id}?behaviour={label}#rollouts",
            server.base
        ),
        &profile,
        &[],
    );
    assert_eq!(rollout_rows(&by_behaviour), same);
    assert!(
        by_behaviour.contains(&format!("<option value=\"{label}\" selected=\"\">"))
            || by_behaviour.contains(&format!("<option value=\"{label}\" selected>"))
    );
    server.kill();
}
