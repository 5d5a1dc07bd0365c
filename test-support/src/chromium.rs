//! Headless Chromium (Debian's `chromium`, installed by `./dev test`) for the
//! page tests, and a one-page server that wraps a page with a test's script.

use std::path::Path;
use std::process::Command;

/// The Chromium command found on this machine; panics with what to install.
pub fn chromium() -> String {
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

/// The flags every headless run gets: no GPU, no network of its own.
pub const HEADLESS: [&str; 8] = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
];

/// The DOM Chromium built for `url` in a window 1400 px wide, after `extra`
/// flags (e.g. a virtual-time budget).
pub fn dump_dom(browser: &str, url: &str, profile: &Path, extra: &[&str]) -> String {
    dump_dom_at(browser, url, profile, 1400, extra)
}

/// The DOM Chromium built for `url` in a window `width` px wide.
pub fn dump_dom_at(browser: &str, url: &str, profile: &Path, width: u32, extra: &[&str]) -> String {
    let out = Command::new(browser)
        .arg(format!("--window-size={width},1000"))
        .args(HEADLESS)
        .args(extra)
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

/// Serves `html` to every request on 127.0.0.1 port 0 from a thread (the
/// site's pages run no script: a test wraps a page with a `<base>` pointing
/// back at the server and its own script); returns the URL.
pub fn serve_forever(html: String) -> String {
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

/// Serves a page of the server at `base` (its text, `page`) as
/// [`serve_forever`] does, wrapped the one way the Chromium tests wrap a
/// page: a `<base>` pointing back at `base` (so that its styles, images
/// and links load from the real server) and the test's own `script` at the
/// end of the body. Returns the URL.
pub fn serve_with_script(page: &str, base: &str, script: &str) -> String {
    let html = page
        .replacen("<head>", &format!("<head><base href=\"{base}/\">"), 1)
        .replacen("</body>", &format!("{script}</body>"), 1);
    serve_forever(html)
}
