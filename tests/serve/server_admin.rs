//! The admin page of the real `d3il serve` lists the sandbox mechanisms in
//! force on this host exactly as `d3il worker --check-sandbox` reports them
//! (issue 6: "the server shows it on the admin page"), and only to an admin
//! token (issue 17).

use crate::{D3IL, EXE};
use d3il_protocol::SandboxMechanism;
use d3il_test_support::server::*;
use std::process::{Command, Stdio};

/// askama's HTML escaping.
fn escape(s: &str) -> String {
    s.replace('&', "&#38;")
        .replace('<', "&#60;")
        .replace('>', "&#62;")
        .replace('"', "&#34;")
        .replace('\'', "&#39;")
}

#[test]
fn admin_page_lists_the_sandbox_mechanisms_the_worker_reports() {
    let assets = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("assets")
        .canonicalize()
        .unwrap();
    // The server below runs jobs with --cpu-seconds 777: its check confines
    // with that limit too.
    let limits = d3il_protocol::Limits {
        cpu_seconds: 777,
        ..Default::default()
    };
    let out = Command::new(EXE)
        .args(["worker", "--check-sandbox", "--json", "--assets"])
        .arg(&assets)
        .arg("--limits-json")
        .arg(serde_json::to_string(&limits).unwrap())
        .stdin(Stdio::null())
        .output()
        .unwrap();
    let expected: Vec<SandboxMechanism> = serde_json::from_slice(&out.stdout).unwrap();

    let dir = TempDir::new("admin");
    let db = dir.path().join("lb.sqlite");
    let assets_s = assets.to_string_lossy().to_string();
    let admin = D3IL.create_admin_token(&db, "operator");
    let submitter = D3IL.create_token(&db, "submitter");
    let server = D3IL.serve(
        &db,
        &[
            "--workers",
            "1",
            "--assets",
            &assets_s,
            "--cpu-seconds",
            "777",
        ],
    );
    let (status, page) = server.get_text_blocking("/admin");
    assert_eq!(status, 401, "anonymous: {page}");
    assert!(page.contains("token create --admin"), "{page}");
    let (status, page) = server.client(Some(&submitter)).get_text("/admin").unwrap();
    assert_eq!(status, 403, "a submitter's token: {page}");
    let (status, page) = server.client(Some(&admin)).get_text("/admin").unwrap();
    assert_eq!(status, 200, "{page}");
    // The limits shown are the configured ones.
    assert!(page.contains("<td>CPU time</td><td>777 s</td>"), "{page}");
    let table = page
        .split("<table class=\"board\" id=\"sandbox\">")
        .nth(1)
        .and_then(|t| t.split("</table>").next())
        .unwrap_or_else(|| panic!("no sandbox table on the admin page:\n{page}"));
    let rows: Vec<&str> = table.split("<tr data-mechanism=").skip(1).collect();
    // The rlimits row shows the configured CPU limit, not the default.
    let rlimits = rows
        .iter()
        .find(|r| r.starts_with("\"rlimits\">"))
        .expect("an rlimits row");
    assert!(rlimits.contains("CPU 777 s"), "{rlimits}");
    assert_eq!(rows.len(), expected.len(), "{table}");
    for (m, row) in expected.iter().zip(&rows) {
        assert!(
            row.starts_with(&format!("\"{}\">", escape(&m.name))),
            "{}: {row}",
            m.name
        );
        assert!(row.contains(&escape(&m.detail)), "{}: {row}", m.name);
        let status = if m.active {
            "<td>active</td>"
        } else {
            "NOT ACTIVE"
        };
        assert!(row.contains(status), "{}: {row}", m.name);
    }
    // Every confinement mechanism is listed (active or not) and so are the probes.
    for name in d3il_sandbox::confine::names::ALL {
        assert!(
            expected.iter().any(|m| m.name == name),
            "{name} missing from --check-sandbox"
        );
    }
    assert!(expected.iter().any(|m| m.name.starts_with("probe:")));
    // The summary matches: everything in force here, or the missing ones named.
    let missing: Vec<&str> = expected
        .iter()
        .filter(|m| !m.active && !m.name.starts_with("probe:"))
        .map(|m| m.name.as_str())
        .collect();
    if missing.is_empty() {
        assert!(
            page.contains(&format!(
                "All {} mechanisms and probes are in force.",
                expected.len()
            )),
            "{page}"
        );
    } else {
        let line = page
            .split("id=\"sandbox-missing\">")
            .nth(1)
            .expect("the missing mechanisms are named");
        for name in missing {
            assert!(line.contains(name), "{name} not named: {line}");
        }
    }
    assert!(page.contains("No evaluation has finished yet."));

    // A revoked admin token opens nothing any more.
    let out = Command::new(EXE)
        .args(["token", "revoke", &admin[..13], "--db"])
        .arg(&db)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let (status, page) = server.client(Some(&admin)).get_text("/admin").unwrap();
    assert_eq!(status, 401, "revoked: {page}");
    server.kill();
}
