//! Every agent fixture (assets/fixtures/agents, one per D3IL method family)
//! completes `d3il eval --task aligning --protocol quick`, including the
//! DDPM-style graphs whose `torch.full((B,), t)` timesteps need the batch bound
//! before optimisation.

use std::process::Command;

const DIR: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/assets/fixtures/agents/");

#[test]
fn every_agent_fixture_completes_a_quick_aligning_evaluation() {
    let mut names: Vec<String> = std::fs::read_dir(DIR)
        .unwrap()
        .filter_map(|e| {
            let n = e.unwrap().file_name().into_string().unwrap();
            n.strip_suffix(".onnx").map(str::to_string)
        })
        .collect();
    names.sort();
    assert!(names.len() >= 8, "{names:?}");
    let scratch = std::env::temp_dir().join(format!("d3il-agents-cli-{}", std::process::id()));
    std::fs::create_dir_all(&scratch).unwrap();
    for name in &names {
        let json = scratch.join(format!("{name}.result.json"));
        let out = Command::new(env!("CARGO_BIN_EXE_d3il"))
            .args([
                "eval",
                "--task",
                "aligning",
                "--protocol",
                "quick",
                "--policy",
            ])
            .arg(format!("{DIR}{name}.onnx"))
            .arg("--json")
            .arg(&json)
            .output()
            .unwrap();
        assert!(
            out.status.success(),
            "{name}: d3il eval failed:\n{}",
            String::from_utf8_lossy(&out.stderr)
        );
        let r: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
        let rollouts = r["rollouts"].as_array().unwrap();
        assert_eq!(rollouts.len(), 6, "{name}");
        assert!(
            rollouts.iter().all(|x| x["steps"].as_u64().unwrap() > 0),
            "{name}"
        );
        let man: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(format!("{DIR}{name}.json")).unwrap())
                .unwrap();
        assert_eq!(r["manifest"]["history"], man["history"], "{name}");
        assert_eq!(r["manifest"]["horizon"], man["horizon"], "{name}");
    }
    std::fs::remove_dir_all(&scratch).unwrap();
}
