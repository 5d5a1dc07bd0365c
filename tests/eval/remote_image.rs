//! An image policy served over the remote protocol (clients/python, started
//! here on 127.0.0.1): the evaluator sends `images` [B, k, 2, 3, 96, 96] next to
//! the low-dimensional `obs`, and the Python side checks what it receives.
//! Needs python3 with numpy, websockets and msgpack.

use serde_json::Value;
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};

const SERVER: &str = r#"
import asyncio, sys
import numpy as np
sys.path.insert(0, sys.argv[1])
from d3il_client.serve import PolicyServer

def policy(obs, req):
    b = obs.shape[0]
    im = req.images
    if im is None:
        raise ValueError("no images in an image-policy request")
    if im.shape != (b, 1, 2, 3, 96, 96) or im.dtype != np.float32:
        raise ValueError(f"images {im.shape} {im.dtype}, expected ({b}, 1, 2, 3, 96, 96) float32")
    if obs.shape != (b, 1, 3):
        raise ValueError(f"obs {obs.shape}, expected ({b}, 1, 3): the previous desired TCP")
    if im.min() < 0.0 or im.max() > 1.0:
        raise ValueError("pixels outside [0, 1]")
    for cam in range(2):
        if im[:, :, cam].std() < 0.02:
            raise ValueError(f"camera {cam} is blank")
    if req.spec["obs_dim"] != 3 or req.spec.get("image_shape") != [2, 3, 96, 96]:
        raise ValueError(f"spec {req.spec}")
    # Move slowly in +x so the frames change over the episode.
    a = np.zeros((b, 3), np.float32)
    a[:, 0] = 0.001
    return a

server = PolicyServer(policy, history=1, horizon=1, execute=1)
asyncio.run(server.run("127.0.0.1", 0, lambda port: print(f"listening on 127.0.0.1:{port}", flush=True)))
"#;

#[test]
fn a_remote_image_policy_gets_both_cameras_and_the_low_dim_obs() {
    let clients = concat!(env!("CARGO_MANIFEST_DIR"), "/clients/python");
    let mut server = Command::new("python3")
        .args(["-c", SERVER, clients])
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .expect("python3 with numpy, websockets, msgpack");
    let mut line = String::new();
    BufReader::new(server.stdout.take().unwrap())
        .read_line(&mut line)
        .unwrap();
    let port: u16 = line.trim().rsplit(':').next().unwrap().parse().unwrap();

    let dir = std::env::temp_dir().join(format!("d3il-remote-image-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let json = dir.join("r.json");
    let run = Command::new(env!("CARGO_BIN_EXE_d3il"))
        .env("RUST_BACKTRACE", "0")
        .args([
            "eval",
            "--task",
            "aligning",
            "--obs-type",
            "image",
            "--protocol",
            "quick",
        ])
        .args(["--allow-private-endpoints", "--policy"])
        .arg(format!("ws://127.0.0.1:{port}/"))
        .arg("--json")
        .arg(&json)
        .output()
        .unwrap();
    let _ = server.kill();
    let _ = server.wait();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let r: Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    assert_eq!(r["manifest"]["obs_type"], "image");
    assert_eq!(r["rollouts"].as_array().unwrap().len(), 6);
    std::fs::remove_dir_all(&dir).unwrap();
}
