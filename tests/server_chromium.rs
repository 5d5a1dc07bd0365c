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
