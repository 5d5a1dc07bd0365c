//! Issue 50: headless Chromium on the Avoiding board of the real `d3il
//! serve` started with the fixture zoo (server/tests/fixtures/zoo): the
//! zoo's row is laid out in a table of its own, and its data-source mark is
//! visible (rendered with a size, not hidden by the stylesheet).

use crate::D3IL;
use d3il_test_support::chromium::{chromium, dump_dom_at, serve_with_script};
use d3il_test_support::server::*;

#[test]
fn chromium_shows_the_zoo_rows_data_source_mark() {
    let browser = chromium();
    let dir = TempDir::new("zoo-chromium");
    let db = dir.path().join("lb.sqlite");
    let zoo = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("server/tests/fixtures/zoo");
    let server = D3IL.serve(&db, &["--workers", "0", "--zoo", zoo.to_str().unwrap()]);
    let (s, page) = server.get_text_blocking("/tasks/avoiding");
    assert_eq!(s, 200);
    // The page, its stylesheet from the server, and a script that measures
    // the mark once everything has loaded (the site's pages run no script).
    let script = "<script>window.addEventListener('load', function () {\
        var t = document.querySelector('table[data-group=\"zoo\"]');\
        var b = t && t.querySelector('.badge-zoo');\
        var r = document.createElement('pre'); r.id = 'zoo-report';\
        if (b) { var box = b.getBoundingClientRect(); var cs = getComputedStyle(b);\
          r.textContent = 'mark ' + Math.round(box.width) + ' ' + Math.round(box.height) + ' ' +\
            cs.visibility + ' ' + cs.display + ' [' + b.textContent + '] end'; }\
        else { r.textContent = 'mark none end'; }\
        document.body.appendChild(r);});</script>";
    let url = serve_with_script(&page, &server.base, script);
    let dom = dump_dom_at(
        &browser,
        &url,
        &dir.path().join("profile"),
        1400,
        &["--hide-scrollbars", "--virtual-time-budget=5000"],
    );
    let report = dom
        .split("<pre id=\"zoo-report\">")
        .nth(1)
        .and_then(|r| r.split(" end").next())
        .expect("the script's report");
    let parts: Vec<&str> = report.splitn(5, ' ').collect();
    assert_eq!(parts[0], "mark", "{report}");
    assert_ne!(parts[1], "none", "no zoo mark in the zoo's table: {report}");
    let (w, h): (i64, i64) = (parts[1].parse().unwrap(), parts[2].parse().unwrap());
    assert!(w > 20 && h > 5, "the mark has a size: {report}");
    assert_eq!(parts[3], "visible", "{report}");
    assert!(
        report.contains("[trained here on d3il demos v1]"),
        "{report}"
    );
    server.kill();
}
