//! `d3il infer`: run an ONNX policy on given inputs and print its raw actions,
//! for an exporter's check that this runtime accepts a file and computes what
//! another runtime (onnxruntime, PyTorch) computes on the same inputs.
//!
//! The file and manifest go through the admission every evaluation and every
//! submission goes through (`d3il_policy::onnx::admit`: the checks of the
//! file, the manifest against the task, the graph analysis and the test
//! inference), so a file this command accepts is one the server accepts.
//! Nothing here loads a scene or computes the physics fingerprint: the task's
//! dimensions come from its definition alone.

use anyhow::{bail, Context};
use d3il_protocol::ObsType;
use serde::{Deserialize, Serialize};
use std::io::Read;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    /// The ONNX file.
    #[arg(long)]
    pub policy: PathBuf,
    /// Its manifest (default: the .onnx path with .json, as for `d3il eval`);
    /// the task is the manifest's.
    #[arg(long)]
    pub manifest: Option<PathBuf>,
    /// The cases, JSON (`-`: standard input): {"cases": [{"batch": B,
    /// "window": w, "obs": [B*w*obs_dim floats], "prev_actions": [B*(w-1)*act_dim
    /// floats] or null, "noise": [B*noise floats] or null}]}. Prints
    /// {"cases": [{"shape": [B, H, act_dim], "actions": [...]}]}, the raw graph
    /// output (no normalisation from the manifest), floats that read back as
    /// the same float32.
    #[arg(long)]
    pub input: PathBuf,
}

/// One set of inputs, as the graph takes them (flattened row-major).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Case {
    pub batch: usize,
    pub window: usize,
    pub obs: Vec<f32>,
    #[serde(default)]
    pub prev_actions: Option<Vec<f32>>,
    #[serde(default)]
    pub noise: Option<Vec<f32>>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Input {
    pub cases: Vec<Case>,
}

/// The graph's output for one case: `[B, H, act_dim]` flattened.
#[derive(Debug, Serialize, Deserialize, PartialEq)]
pub struct Output {
    pub shape: [usize; 3],
    pub actions: Vec<f32>,
}

#[derive(Debug, Serialize, Deserialize, PartialEq)]
pub struct Outputs {
    pub cases: Vec<Output>,
}

/// The cases of `path` (`-`: standard input), checked for form only.
pub fn read_input(path: &Path) -> anyhow::Result<Input> {
    let text = if path == Path::new("-") {
        let mut s = String::new();
        std::io::stdin()
            .read_to_string(&mut s)
            .context("reading the cases from standard input")?;
        s
    } else {
        std::fs::read_to_string(path)
            .with_context(|| format!("reading the cases file {}", path.display()))?
    };
    let input: Input = serde_json::from_str(&text).with_context(|| {
        format!(
            "{} is not a cases file: expected {{\"cases\": [{{\"batch\": B, \"window\": w, \"obs\": [...], \"prev_actions\": [...] or null, \"noise\": [...] or null}}]}} (d3il infer --help)",
            path.display()
        )
    })?;
    if input.cases.is_empty() {
        bail!("{} has no cases; give at least one", path.display());
    }
    Ok(input)
}

/// Admits the policy as an evaluation does and runs every case.
pub fn infer(onnx: &Path, manifest: Option<&Path>, input: &Input) -> anyhow::Result<Outputs> {
    let (mpath, _, man) = crate::common::evaluation::read_manifest(onnx, manifest)?;
    if man.obs_type == ObsType::Image {
        bail!(
            "{} is an image policy's manifest; d3il infer runs state policies (inputs obs, prev_actions, noise)",
            mpath.display()
        );
    }
    let bytes =
        std::fs::read(onnx).with_context(|| format!("reading the ONNX file {}", onnx.display()))?;
    // The task's dimensions without loading its scene.
    let spec = d3il_evaluator::tasks::task_def(man.task)?.spec_for(man.obs_type);
    let policy = d3il_policy::onnx::admit(&bytes, &man, &spec, 0).map_err(|e| {
        anyhow::anyhow!(
            "{} was refused as a policy for {} ({}): {e}",
            onnx.display(),
            man.task,
            mpath.display()
        )
    })?;
    let mut cases = Vec::with_capacity(input.cases.len());
    for (i, c) in input.cases.iter().enumerate() {
        let actions = policy
            .run_explicit(
                c.batch,
                c.window,
                &c.obs,
                c.prev_actions.as_deref(),
                c.noise.as_deref(),
            )
            .map_err(|e| {
                anyhow::anyhow!("case {i} (batch {}, window {}): {e}", c.batch, c.window)
            })?;
        if let Some(j) = actions.iter().position(|a| !a.is_finite()) {
            bail!(
                "case {i}: the model returned a non-finite action ({} at position {j}); the evaluator refuses such actions",
                actions[j]
            );
        }
        let horizon = actions.len() / (c.batch * spec.act_dim);
        cases.push(Output {
            shape: [c.batch, horizon, spec.act_dim],
            actions,
        });
    }
    Ok(Outputs { cases })
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // The cases are read (and their form checked) before the model is loaded.
    let input = read_input(&args.input)?;
    let out = infer(&args.policy, args.manifest.as_deref(), &input)?;
    // serde_json writes an f32 as the shortest decimal that reads back as it.
    println!("{}", serde_json::to_string(&out)?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn agent(name: &str) -> PathBuf {
        crate::common::assets_dir()
            .join("fixtures/agents")
            .join(format!("{name}.onnx"))
    }

    fn floats(v: &serde_json::Value) -> Vec<f32> {
        v["data"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap() as f32)
            .collect()
    }

    /// The recorded onnxruntime inputs of a fixture as cases, with its outputs.
    fn recorded(name: &str) -> (Input, Vec<Vec<f32>>) {
        let rec: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(agent(name).with_extension("ort.json")).unwrap(),
        )
        .unwrap();
        let mut cases = vec![];
        let mut want = vec![];
        for c in rec["cases"].as_array().unwrap() {
            let ins = &c["inputs"];
            cases.push(Case {
                batch: ins["obs"]["shape"][0].as_u64().unwrap() as usize,
                window: c["window"].as_u64().unwrap() as usize,
                obs: floats(&ins["obs"]),
                prev_actions: ins.get("prev_actions").map(floats),
                noise: ins.get("noise").map(floats),
            });
            want.push(floats(&c["actions"]));
        }
        (Input { cases }, want)
    }

    #[test]
    fn beso_gives_onnxruntimes_actions_on_its_recorded_inputs() {
        let (input, want) = recorded("beso");
        assert!(input.cases.len() > 1, "beso grows its window");
        let out = infer(&agent("beso"), None, &input).unwrap();
        assert_eq!(out.cases.len(), want.len());
        for ((got, want), case) in out.cases.iter().zip(&want).zip(&input.cases) {
            assert_eq!(got.shape[0], case.batch);
            assert_eq!(got.shape[2], 3, "Aligning acts in 3 dimensions");
            assert_eq!(got.actions.len(), got.shape.iter().product::<usize>());
            assert_eq!(got.actions.len(), want.len());
            // The tolerance of policy/tests/policies/agent_fixtures.rs.
            let worst = got
                .actions
                .iter()
                .zip(want)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0f32, f32::max);
            assert!(worst <= 1e-6, "window {}: {worst:e}", case.window);
        }
        // The printed floats read back as the same float32, bit for bit.
        let text = serde_json::to_string(&out).unwrap();
        let back: Outputs = serde_json::from_str(&text).unwrap();
        for (a, b) in back.cases.iter().zip(&out.cases) {
            assert!(a
                .actions
                .iter()
                .zip(&b.actions)
                .all(|(x, y)| x.to_bits() == y.to_bits()));
        }
    }

    #[test]
    fn wrong_lengths_and_missing_inputs_name_the_input() {
        let (input, _) = recorded("beso");
        let good = &input.cases[input.cases.len() - 1];
        let case = |f: &dyn Fn(&mut Case)| {
            let mut c = Case {
                batch: good.batch,
                window: good.window,
                obs: good.obs.clone(),
                prev_actions: good.prev_actions.clone(),
                noise: good.noise.clone(),
            };
            f(&mut c);
            let e = infer(&agent("beso"), None, &Input { cases: vec![c] }).unwrap_err();
            format!("{e:#}")
        };
        let m = case(&|c| {
            c.obs.pop();
        });
        assert!(m.contains("case 0") && m.contains("`obs` has"), "{m}");
        let m = case(&|c| c.noise = None);
        assert!(m.contains("takes `noise`"), "{m}");
        let m = case(&|c| c.window = 99);
        assert!(m.contains("window 99"), "{m}");
    }

    #[test]
    fn a_refused_manifest_is_an_error_with_the_admissions_reason() {
        let dir = std::env::temp_dir().join(format!("d3il-infer-unit-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let man = dir.join("beso.json");
        let mut m: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(agent("beso").with_extension("json")).unwrap(),
        )
        .unwrap();
        m["task"] = "avoiding".into();
        std::fs::write(&man, m.to_string()).unwrap();
        let (input, _) = recorded("beso");
        let e = infer(&agent("beso"), Some(&man), &input).unwrap_err();
        let msg = format!("{e:#}");
        assert!(
            msg.contains("was refused as a policy for avoiding"),
            "{msg}"
        );
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
