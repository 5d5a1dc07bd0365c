//! The admin page against a real server on 127.0.0.1 (port 0): what it says
//! about the sandbox mechanisms the kernel offers and lacks.

use d3il_test_support::server::*;

#[tokio::test]
async fn admin_page_says_when_the_sandbox_check_cannot_run() {
    // spawn_app's worker executable is /bin/false: it prints no mechanism list.
    let app = spawn_app().await;
    let (s, page) = app.get_admin_text("/admin").await;
    assert_eq!(s, 200);
    let e = page
        .split("id=\"sandbox-error\">")
        .nth(1)
        .expect("the failed check is reported");
    assert!(
        e.starts_with("The sandbox check could not run: `/bin/false  --check-sandbox` (exit status: 1) printed no mechanism list"),
        "{e}"
    );
    assert!(!page.contains("id=\"sandbox\""), "no table without a check");
}

/// A worker executable (a real process) whose `--check-sandbox` reports what a
/// kernel without landlock network rules reports.
fn worker_lacking_landlock_net(dir: &std::path::Path) -> std::path::PathBuf {
    let list = serde_json::json!([
        {"name": "rlimits", "active": true, "detail": "address space 4 GiB"},
        {"name": "landlock-net", "active": false, "detail": "kernel landlock ABI v3 < 4: no TCP rules"},
        {"name": "seccomp", "active": true, "detail": "denied (EPERM): fork <& co>"},
        {"name": "probe:fork", "active": true, "detail": "denied as it must be"}
    ]);
    let json = dir.join("check.json");
    std::fs::write(&json, list.to_string()).unwrap();
    let script = dir.join("worker.sh");
    std::fs::write(
        &script,
        format!(
            "#!/bin/sh\n[ \"$1\" = --check-sandbox ] && cat '{}'\n",
            json.display()
        ),
    )
    .unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&script, std::fs::Permissions::from_mode(0o755)).unwrap();
    script
}

#[tokio::test]
async fn admin_page_names_mechanisms_the_kernel_lacks() {
    let dir = tempfile::tempdir().unwrap();
    let app = spawn_app_with(Options {
        worker_exe: Some(worker_lacking_landlock_net(dir.path())),
        ..Options::default()
    })
    .await;
    let (s, page) = app.get_admin_text("/admin").await;
    assert_eq!(s, 200);
    let missing = page
        .split("id=\"sandbox-missing\">")
        .nth(1)
        .and_then(|p| p.split("</p>").next())
        .expect("the missing mechanism is named");
    assert!(
        missing.starts_with("Not in force on this host: landlock-net."),
        "{missing}"
    );
    let row = page
        .split("<tr data-mechanism=\"landlock-net\">")
        .nth(1)
        .and_then(|r| r.split("</tr>").next())
        .expect("landlock-net row");
    assert!(
        row.contains("NOT ACTIVE") && row.contains("kernel landlock ABI v3 &#60; 4: no TCP rules"),
        "{row}"
    );
    // Details are escaped, probes listed, nothing breached.
    assert!(page.contains("denied (EPERM): fork &#60;&#38; co&#62;"));
    assert!(page.contains("<tr data-mechanism=\"probe:fork\">"));
    assert!(!page.contains("sandbox-breached"));
}
