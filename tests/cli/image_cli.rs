//! Image observations through the real binary: `d3il render` writes what an
//! image policy sees, and an image-input ONNX policy runs through `d3il eval`
//! (inside the sandboxed worker, which renders headless under landlock and
//! seccomp) under the quick protocol.

use d3il_test_support::TempDir;
use serde_json::Value;
use std::process::Command;

fn d3il() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_d3il"));
    c.env("RUST_BACKTRACE", "0");
    c
}

#[test]
fn render_writes_both_cameras_side_by_side() {
    let tmp = TempDir::new("render");
    let dir = tmp.path().to_path_buf();
    let out = dir.join("frame.png");
    let run = d3il()
        .args(["render", "--task", "sorting-4", "--context", "2", "--out"])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let decoder = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(&out).unwrap()));
    let mut reader = decoder.read_info().unwrap();
    let mut buf = vec![0; reader.output_buffer_size().unwrap()];
    let info = reader.next_frame(&mut buf).unwrap();
    assert_eq!(
        (info.width, info.height),
        (192, 96),
        "two 96x96 cameras side by side"
    );
    assert_eq!(info.color_type, png::ColorType::Rgb);
    // Both halves show a scene, and they differ (front view vs in-hand).
    let half = |x0: usize| -> Vec<u8> {
        (0..96)
            .flat_map(|y| buf[(y * 192 + x0) * 3..(y * 192 + x0 + 96) * 3].to_vec())
            .collect()
    };
    let (left, right) = (half(0), half(96));
    for (name, h) in [("front", &left), ("in-hand", &right)] {
        let distinct: std::collections::HashSet<&[u8]> = h.chunks(3).collect();
        assert!(
            distinct.len() > 20,
            "{name} view looks blank ({} colours)",
            distinct.len()
        );
    }
    assert_ne!(left, right);
    // Some pixels of the front view are the red boxes' colour.
    let reddish = left
        .chunks(3)
        .filter(|p| p[0] > 150 && p[1] < 100 && p[2] < 100)
        .count();
    assert!(
        reddish > 5,
        "no red box pixels in the front view ({reddish})"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn render_names_the_bad_argument() {
    let tmp = TempDir::new("render-bad");
    let dir = tmp.path().to_path_buf();
    let run = d3il()
        .args(["render", "--task", "aligning", "--context", "60", "--out"])
        .arg(dir.join("x.png"))
        .output()
        .unwrap();
    assert!(!run.status.success());
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(
        err.contains("--context 60 is out of range") && err.contains("60 initial states"),
        "{err}"
    );
    assert!(!dir.join("x.png").exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn image_onnx_policy_runs_through_sandboxed_eval_quick() {
    let tmp = TempDir::new("image-eval");
    let dir = tmp.path().to_path_buf();
    let json = dir.join("result.json");
    let fixture = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/assets/fixtures/aligning_image.onnx"
    );
    let run = d3il()
        .args([
            "eval",
            "--task",
            "aligning",
            "--protocol",
            "quick",
            "--sandbox",
            "--policy",
            fixture,
            "--json",
        ])
        .arg(&json)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "{stderr}");
    // The worker was confined while it rendered.
    assert!(
        stderr.contains("landlock-fs active") && stderr.contains("seccomp active"),
        "{stderr}"
    );
    let r: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let m = &r["manifest"];
    assert_eq!(m["obs_type"], "image");
    assert_eq!(
        m["robot_look"], "meshes",
        "the set-up converts the Panda meshes"
    );
    assert_eq!(m["task"], "aligning");
    assert_eq!(m["max_steps"], 400);
    let rollouts = r["rollouts"].as_array().unwrap();
    assert_eq!(rollouts.len(), 6, "quick protocol: 3 contexts x 2 rollouts");
    // The fixture nudges the arm by 0.001 x mean pixel value per step: it
    // never aligns the box, so every rollout runs to the episode limit.
    for x in rollouts {
        assert_eq!(x["success"], false);
        assert_eq!(x["steps"], 400);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
