//! Headless Chromium (Debian's `chromium`, installed by .ci/run) loads the
//! Aligning leaderboard served by the real `d3il serve` and we check the DOM it
//! rendered: the table with the paper's eleven reported rows and the embedded
//! Pareto plot.

use crate::D3IL;
use d3il_test_support::chromium::{chromium, dump_dom, dump_dom_at, serve_with_script};
use d3il_test_support::server::*;

#[test]
fn chromium_renders_the_leaderboard_table_and_plot() {
    let browser = chromium();
    let dir = TempDir::new("chromium");
    let db = dir.path().join("lb.sqlite");
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let dom = dump_dom(
        &browser,
        &format!("{}/tasks/aligning?sort=success&dir=desc", server.base),
        &dir.path().join("profile"),
        &[],
    );

    // The browser parsed a leaderboard table with the paper's rows.
    let table_start = dom
        .find("<table class=\"board leaderboard\"")
        .expect("leaderboard table in the DOM");
    let table = &dom[table_start
        ..dom[table_start..]
            .find("</table>")
            .map(|e| table_start + e)
            .expect("table end")];
    assert_eq!(
        table.matches("<tr class=\"reported\">").count(),
        11,
        "eleven reported rows"
    );
    for m in d3il_protocol::paper::PAPER_METHOD_ORDER {
        assert!(table.contains(&format!(">{m}</a>")), "{m} in the table");
    }
    assert!(table.contains("badge-reported"));
    // Sorted by success, descending: the first row's success is the largest.
    let successes: Vec<f64> = table
        .split("<td class=\"num success")
        .skip(1)
        .filter_map(|c| c.split('>').nth(1)?.split(' ').next()?.parse().ok())
        .collect();
    assert_eq!(successes.len(), 11);
    assert!(successes.windows(2).all(|w| w[0] >= w[1]), "{successes:?}");
    // The embedded plot: an inline SVG inside the figure, with points and the front.
    let fig = &dom[dom.find("<figure class=\"plot\">").expect("plot figure")..];
    let svg = &fig[..fig.find("</svg>").expect("inline svg")];
    assert!(svg.contains("<svg"));
    assert!(svg.matches("<circle").count() >= 11, "one point per method");
    assert!(svg.contains("Pareto front"));
    assert!(svg.contains("Success rate") && svg.contains("Conditional behaviour entropy"));
    server.kill();
}

/// The page's horizontal extent as Chromium lays it out at `width` px:
/// (document scroll width, viewport client width). The page is fetched from
/// the real server and served with a `<base>` pointing back at it (so its
/// stylesheet and plots load from the server) and a script that writes the
/// measurement into the DOM once everything has loaded.
fn layout_widths(
    browser: &str,
    server: &TestServer,
    path: &str,
    width: u32,
    profile: &std::path::Path,
) -> (i64, i64) {
    let (s, page) = server.get_text_blocking(path);
    assert_eq!(s, 200, "{path}");
    let script = "<script>window.addEventListener('load', function () {\
        var d = document.documentElement;\
        var r = document.createElement('pre'); r.id = 'layout-report';\
        r.textContent = 'widths ' + Math.max(d.scrollWidth, document.body.scrollWidth) + ' ' + d.clientWidth + ' end';\
        document.body.appendChild(r);});</script>";
    let url = serve_with_script(&page, &server.base, script);
    let dom = dump_dom_at(
        browser,
        &url,
        profile,
        width,
        &["--hide-scrollbars", "--virtual-time-budget=5000"],
    );
    let report = dom
        .split("<pre id=\"layout-report\">widths ")
        .nth(1)
        .and_then(|r| r.split(" end").next())
        .unwrap_or_else(|| panic!("no layout report for {path} at {width} px"));
    let v: Vec<i64> = report
        .split(' ')
        .map(|x| x.parse().expect("width"))
        .collect();
    (v[0], v[1])
}

#[test]
fn pages_have_no_horizontal_overflow_at_1400_and_760_px() {
    let browser = chromium();
    let dir = TempDir::new("chromium-layout");
    let db = dir.path().join("lb.sqlite");
    let server = D3IL.serve(&db, &["--workers", "0"]);
    for width in [1400, 760] {
        for path in [
            "/",
            "/tasks/aligning",
            "/tasks/stacking?obs=image",
            "/tasks/aligning/data-fraction",
            "/tasks/pushing/data-fraction",
            "/methods",
            "/?obs=image",
            "/compare",
        ] {
            let (scroll, client) = layout_widths(
                &browser,
                &server,
                path,
                width,
                &dir.path().join(format!("profile-{width}")),
            );
            assert!(
                client > 0 && client <= width as i64,
                "{path} at {width}: viewport {client}"
            );
            assert!(
                scroll <= client,
                "{path} at {width} px overflows horizontally: content {scroll} px, viewport {client} px"
            );
        }
    }
    server.kill();
}

/// The paper's main table on the home page, as Chromium builds it at 1400
/// and 760 px: one table per block of three tasks, the paper's eleven
/// methods in their two groups, success and entropy per task, and every cell
/// linking to its task's board; the page body does not overflow.
#[test]
fn chromium_renders_the_home_page_main_table_at_1400_and_760_px() {
    let browser = chromium();
    let dir = TempDir::new("chromium-home");
    let db = dir.path().join("lb.sqlite");
    let server = D3IL.serve(&db, &["--workers", "0"]);
    for width in [1400, 760] {
        let profile = dir.path().join(format!("profile-home-{width}"));
        let dom = dump_dom_at(&browser, &format!("{}/", server.base), &profile, width, &[]);
        let tables: Vec<&str> = dom
            .split("<table class=\"board main-table\"")
            .skip(1)
            .map(|t| &t[..t.find("</table>").expect("table end")])
            .collect();
        assert_eq!(
            tables.len(),
            3,
            "three blocks of three tasks (state, Table 2)"
        );
        let first = tables[0];
        for task in ["Avoiding (T1)", "Aligning (T2)", "Pushing (T3)"] {
            assert!(first.contains(task), "{task} column");
        }
        assert!(first.contains("<a href=\"/tasks/avoiding?obs=state#avoiding-t1\">"));
        assert_eq!(first.matches("<tr class=\"reported\">").count(), 11);
        assert_eq!(first.matches(">Success</th>").count(), 3);
        assert_eq!(first.matches(">Entropy</th>").count(), 3);
        assert!(first.contains("History-free methods") && first.contains("History-based methods"));
        assert!(first.contains("class=\"num best\""), "bold values");
        assert!(
            dom.contains("id=\"how-to-read\""),
            "grouping and bold explained"
        );
        let (scroll, client) = layout_widths(&browser, &server, "/", width, &profile);
        assert!(
            scroll <= client,
            "home page at {width} px overflows: {scroll} > {client}"
        );
    }
    server.kill();
}

/// Two finished Pushing submissions written into the database as a worker
/// would (the store's claim and completion), before the server starts.
fn two_finished_submissions(db: &std::path::Path) -> (i64, i64) {
    use d3il_protocol::*;
    let result = |k: usize| {
        d3il_test_support::pushing_result(ProtocolKind::Paper, |c, r| {
            d3il_test_support::SynthRollout {
                success: r < k + c % 3,
                label: r % 2,
                unstable: false,
            }
        })
    };
    with_sqlite_store(db, async |store| {
        let mut ids = vec![];
        for (name, k) in [("Alpha", 12), ("Beta", 6)] {
            let done = Finished::Evaluation(&result(k));
            ids.push(finished_pushing(store, name, 0, done).await);
        }
        (ids[0], ids[1])
    })
}

/// The compare page for two finished submissions, as Chromium renders it at
/// 1400 and 760 px: the paired differences, both behaviour histograms and
/// the per-state table, without horizontal overflow of the page body.
#[test]
fn chromium_renders_the_compare_page_for_two_finished_submissions() {
    let browser = chromium();
    let dir = TempDir::new("chromium-compare");
    let db = dir.path().join("lb.sqlite");
    let (a, b) = two_finished_submissions(&db);
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let path = format!("/compare?a={a}&b={b}");
    for width in [1400, 760] {
        let profile = dir.path().join(format!("profile-compare-{width}"));
        let dom = dump_dom_at(
            &browser,
            &format!("{}{path}", server.base),
            &profile,
            width,
            &[],
        );
        let diffs = &dom[dom.find("id=\"differences\"").expect("differences table")..];
        let diffs = &diffs[..diffs.find("</table>").expect("end")];
        // Alpha succeeds in 12 + c % 3, Beta in 6 + c % 3 of 16: A − B = 6/16.
        assert!(diffs.contains(">+0.375<"), "{diffs}");
        assert!(diffs.contains("Conditional behaviour entropy"));
        for id in ["behaviours-a", "behaviours-b"] {
            let fig = &dom[dom.find(&format!("id=\"{id}\"")).expect("histogram")..];
            assert!(fig[..fig.find("</figure>").expect("end")].contains("<svg"));
        }
        let ctx = &dom[dom.find("id=\"contexts\"").expect("per-state table")..];
        let ctx = &ctx[..ctx.find("</table>").expect("end")];
        assert_eq!(ctx.matches("<tr>").count(), 31, "header and 30 states");
        let (scroll, client) = layout_widths(&browser, &server, &path, width, &profile);
        assert!(
            scroll <= client,
            "compare page at {width} px overflows: {scroll} > {client}"
        );
    }
    server.kill();
}
