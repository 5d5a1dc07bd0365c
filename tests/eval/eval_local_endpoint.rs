//! Issue 39 item 3, "local endpoints just work": `d3il eval --policy
//! ws://127.0.0.1:PORT/` (and `localhost`, `[::1]`) evaluates the Python
//! reference policy server (`python3 -m d3il_client.serve --demo avoiding`)
//! without any flag; a user's own evaluation connects to whatever address
//! they name, private ones included. Only a server refuses loopback and
//! private endpoints of submissions (tests/serve/server_dry_run.rs).
//!
//! Needs python3 with numpy, websockets and msgpack (the `serve` extra of
//! clients/python).

use d3il_test_support::listening::Listening;
use std::process::{Command, Output};

const EXE: &str = env!("CARGO_BIN_EXE_d3il");

/// The reference demo server on `host`; killed when dropped.
fn start(host: &str) -> Listening {
    Listening::spawn(
        Command::new("python3")
            .args([
                "-m",
                "d3il_client.serve",
                "--demo",
                "avoiding",
                "--port",
                "0",
            ])
            .args(["--host", host])
            .env(
                "PYTHONPATH",
                concat!(env!("CARGO_MANIFEST_DIR"), "/clients/python"),
            ),
        "python3 with numpy, websockets and msgpack",
    )
}

fn eval(url: &str, extra: &[&str]) -> Output {
    Command::new(EXE)
        .args([
            "eval",
            "--task",
            "avoiding",
            "--protocol",
            "quick",
            "--policy",
        ])
        .arg(url)
        .args(extra)
        .output()
        .unwrap()
}

fn assert_evaluated(url: &str, out: &Output) {
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "d3il eval --policy {url} failed:\n{stdout}\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.starts_with("task avoiding"), "{url}: {stdout}");
}

#[test]
fn eval_connects_to_a_loopback_endpoint_without_a_flag() {
    let v4 = start("127.0.0.1");
    let url = format!("ws://127.0.0.1:{}/", v4.port);
    assert_evaluated(&url, &eval(&url, &[]));
    // `localhost` resolves here to loopback addresses; the one the server
    // listens on is found whichever comes first.
    let url = format!("ws://localhost:{}/", v4.port);
    assert_evaluated(&url, &eval(&url, &[]));
    // The flag of older versions is still accepted (and changes nothing).
    let url = format!("ws://127.0.0.1:{}/", v4.port);
    assert_evaluated(&url, &eval(&url, &["--allow-private-endpoints"]));
    drop(v4);
    let v6 = start("::1");
    let url = format!("ws://[::1]:{}/", v6.port);
    assert_evaluated(&url, &eval(&url, &[]));
}

#[test]
fn a_private_lan_address_is_tried_not_refused() {
    // 10.255.255.1 is a private address nothing here listens on: the
    // evaluation tries to connect (and fails to) instead of refusing the
    // address as the server would.
    let out = eval("ws://10.255.255.1:9/", &["--remote-deadline-ms", "300"]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("could not connect to the policy server at `ws://10.255.255.1:9/`"),
        "{stderr}"
    );
    assert!(!stderr.contains("public addresses"), "{stderr}");
    // Addresses no server can be reached at are refused with what to use.
    let out = eval("ws://0.0.0.0:9/", &[]);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{stderr}");
    assert!(
        stderr.contains("unspecified") && stderr.contains("127.0.0.1"),
        "{stderr}"
    );
}
