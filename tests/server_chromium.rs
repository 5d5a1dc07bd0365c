//! Headless Chromium (Debian's `chromium`, installed by .ci/run) loads the
//! Aligning leaderboard served by the real `d3il serve` and we check the DOM it
//! rendered: the table with the paper's eleven reported rows and the embedded
//! Pareto plot.

mod server_support;
use server_support::*;
use std::process::Command;

fn chromium() -> String {
    for c in ["chromium", "chromium-browser", "google-chrome"] {
        if Command::new(c)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success())
        {
            return c.to_string();
        }
    }
    panic!(
        "headless Chromium is required for this test: apt-get install -y chromium chromium-driver"
    );
}

fn dump_dom(browser: &str, url: &str, profile: &std::path::Path) -> String {
    let out = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--dump-dom")
        .arg(url)
        .output()
        .expect("run chromium");
    assert!(
        out.status.success(),
        "chromium failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf8 DOM")
}

#[test]
fn chromium_renders_the_leaderboard_table_and_plot() {
    let browser = chromium();
    let dir = TempDir::new("chromium");
    let db = dir.path().join("lb.sqlite");
    let server = Server::start(&db, &["--workers", "0"]);
    let dom = dump_dom(
        &browser,
        &format!("{}/tasks/aligning?sort=success&dir=desc", server.base),
        &dir.path().join("profile"),
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
    for m in [
        "BC-MLP",
        "VAE-State",
        "BeT-MLP",
        "IBC",
        "DDPM-MLP",
        "VAE-ACT",
        "BC-GPT",
        "BeT",
        "DDPM-GPT",
        "BESO",
        "DDPM-ACT",
    ] {
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

/// Serves `html` (every request gets it) on 127.0.0.1 port 0 from a thread;
/// returns the URL.
fn serve_once_forever(html: String) -> String {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind 127.0.0.1");
    let addr = listener.local_addr().expect("addr");
    std::thread::spawn(move || {
        for stream in listener.incoming() {
            let Ok(mut s) = stream else { continue };
            let mut buf = [0u8; 8192];
            let _ = s.read(&mut buf);
            let _ = write!(
                s,
                "HTTP/1.1 200 OK\r\nContent-Type: text/html; charset=utf-8\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{}",
                html.len(),
                html
            );
        }
    });
    format!("http://{addr}/")
}

/// The page's horizontal extent as Chromium lays it out at `width` px:
/// (document scroll width, viewport client width). The page is fetched from
/// the real server and served with a `<base>` pointing back at it (so its
/// stylesheet and plots load from the server) and a script that writes the
/// measurement into the DOM once everything has loaded.
fn layout_widths(
    browser: &str,
    server: &Server,
    path: &str,
    width: u32,
    profile: &std::path::Path,
) -> (i64, i64) {
    let (s, page) = server.get_text(path);
    assert_eq!(s, 200, "{path}");
    let script = "<script>window.addEventListener('load', function () {\
        var d = document.documentElement;\
        var r = document.createElement('pre'); r.id = 'layout-report';\
        r.textContent = 'widths ' + Math.max(d.scrollWidth, document.body.scrollWidth) + ' ' + d.clientWidth + ' end';\
        document.body.appendChild(r);});</script>";
    let html = page
        .replacen(
            "<head>",
            &format!("<head><base href=\"{}/\">", server.base),
            1,
        )
        .replacen("</body>", &format!("{script}</body>"), 1);
    let url = serve_once_forever(html);
    let out = Command::new(browser)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            "--virtual-time-budget=5000",
        ])
        .arg(format!("--window-size={width},1000"))
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg("--dump-dom")
        .arg(&url)
        .output()
        .expect("run chromium");
    assert!(
        out.status.success(),
        "chromium failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let dom = String::from_utf8(out.stdout).expect("utf8 DOM");
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
    let server = Server::start(&db, &["--workers", "0"]);
    for width in [1400, 760] {
        for path in [
            "/",
            "/tasks/aligning",
            "/tasks/stacking?obs=image",
            "/tasks/aligning/data-fraction",
            "/tasks/pushing/data-fraction",
            "/methods",
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
