//! `d3il submit`: submit a policy to a leaderboard server through its API.

pub mod race;

use anyhow::Context;
use std::path::PathBuf;
use std::time::Duration;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Server root URL.
    #[arg(long, default_value = "http://127.0.0.1:8080")]
    pub server: String,
    /// API token (or set D3IL_TOKEN).
    #[arg(long)]
    pub token: Option<String>,
    /// Method name.
    #[arg(long, required_unless_present_any = ["cancel", "cancel_race", "race"])]
    pub method: Option<String>,
    /// Task slug (avoiding, aligning, pushing, sorting-2/4/6, stacking, inserting).
    #[arg(long, required_unless_present_any = ["cancel", "cancel_race", "race"])]
    pub task: Option<String>,
    /// Observation type: `state` or `image` (must match the manifest).
    #[arg(long, default_value = "state")]
    pub obs_type: String,
    /// Training seed of this policy (0, 1, ...): the seeds of one method,
    /// task and setting are aggregated into one leaderboard row (mean ± std).
    #[arg(long, required_unless_present_any = ["cancel", "cancel_race", "race"])]
    pub training_seed: Option<i64>,
    /// Fraction of the demonstrations the policy was trained on (0 < f ≤ 1;
    /// below 1 it shows in the data-fraction view).
    #[arg(long, default_value_t = 1.0)]
    pub data_fraction: f64,
    /// `paper` (full protocol) or `quick` (smoke test).
    #[arg(long, default_value = "paper")]
    pub protocol: String,
    /// `robustness`: evaluate the task's perturbation suite too (level 0 is
    /// the plain result; docs/robustness.md). Every task for state
    /// policies; Aligning, Sorting-4/6 and Stacking for image policies.
    #[arg(long)]
    pub suite: Option<d3il_protocol::SuiteName>,
    /// ONNX policy file.
    #[arg(long, conflicts_with = "endpoint")]
    pub onnx: Option<PathBuf>,
    /// Policy manifest JSON file for --onnx (default: the .onnx path with
    /// .json, as `d3il eval` finds it).
    #[arg(long)]
    pub manifest: Option<PathBuf>,
    /// Remote policy endpoint URL (instead of --onnx). With
    /// $D3IL_ENDPOINT_SECRET set, the evaluator sends that shared secret to
    /// the endpoint (docs/remote-protocol.md); the server never shows it.
    #[arg(long)]
    pub endpoint: Option<String>,
    /// Method metadata: observation history length k (1 = history-free;
    /// decides the method's group in the paper's tables).
    #[arg(long)]
    pub history: Option<u32>,
    /// Method metadata: the network backbone (e.g. `MLP`, `GPT`).
    #[arg(long)]
    pub backbone: Option<String>,
    /// Method metadata: what the policy predicts (e.g. `single action`,
    /// `action chunk`; a chunk marks the method † in the tables).
    #[arg(long)]
    pub prediction: Option<String>,
    /// Method metadata: where its diversity comes from (e.g. `diffusion`).
    #[arg(long)]
    pub diversity: Option<String>,
    /// Method metadata: URL of the method's code.
    #[arg(long)]
    pub code_url: Option<String>,
    /// Method metadata: URL of the method's paper.
    #[arg(long)]
    pub paper_url: Option<String>,
    /// One-paragraph description of the method (shown on its page).
    #[arg(long)]
    pub description: Option<String>,
    /// Wait for the evaluation and print its metrics table (as `d3il eval`).
    #[arg(long)]
    pub wait: bool,
    /// With --wait: print the server's full JSON document of the submission
    /// instead of the table.
    #[arg(long, requires = "wait")]
    pub json: bool,
    /// Give up waiting after this many seconds.
    #[arg(long, default_value_t = 7200)]
    pub timeout: u64,
    /// Cancel the queued or running evaluation of submission ID (`POST
    /// /api/v1/submissions/{id}/cancel`): what ran is kept, marked partial.
    #[arg(long, value_name = "ID", conflicts_with_all = ["race", "onnx", "endpoint"])]
    pub cancel: Option<i64>,
    /// Cancel the queued or running race ID (`POST
    /// /api/v1/races/{id}/cancel`; its starter or an admin): its
    /// worker is stopped.
    #[arg(long, value_name = "ID", conflicts_with_all = ["cancel", "race", "onnx", "endpoint"])]
    pub cancel_race: Option<i64>,
    /// Race submissions A and B sequentially on the server (`POST
    /// /api/v1/races`): both policies on the same initial states in
    /// the same random order, stopping when the anytime-valid paired test
    /// decides (docs/sequential.md). Uses --protocol, --alpha, --delta,
    /// --wait and --json.
    #[arg(long, num_args = 2, value_names = ["A", "B"], conflicts_with_all = ["onnx", "endpoint"])]
    pub race: Option<Vec<i64>>,
    /// With --race: the level of the sequential test.
    #[arg(long, default_value_t = 0.05, requires = "race")]
    pub alpha: f64,
    /// With --race: also stop with "no difference larger than δ".
    #[arg(long, requires = "race")]
    pub delta: Option<f64>,
}

/// The checks the server would make that need no server, before anything is
/// uploaded (a model can take minutes to upload): the names of the
/// task, observation type and protocol, the seed and data fraction, the
/// policy file, the manifest against --task and --obs-type, the endpoint's
/// scheme. The server checks all of it again, and more.
fn check_locally(a: &Args, task: &str, training_seed: i64) -> anyhow::Result<()> {
    let task: d3il_protocol::TaskId = task
        .parse()
        .map_err(|e| anyhow::anyhow!("--task {task}: {e}"))?;
    let obs_type: d3il_protocol::ObsType = a
        .obs_type
        .parse()
        .map_err(|e| anyhow::anyhow!("--obs-type {}: {e}", a.obs_type))?;
    a.protocol
        .parse::<d3il_protocol::ProtocolKind>()
        .map_err(|e| anyhow::anyhow!("--protocol {}: {e}", a.protocol))?;
    if let Some(suite) = &a.suite {
        d3il_evaluator::robustness::suite_for(*suite, task, obs_type)
            .map_err(|e| anyhow::anyhow!("--suite {suite}: {e}"))?;
    }
    anyhow::ensure!(
        (0..=i64::from(i32::MAX)).contains(&training_seed),
        "--training-seed must be a whole number from 0 to 2147483647, got {training_seed}"
    );
    anyhow::ensure!(
        a.data_fraction > 0.0 && a.data_fraction <= 1.0,
        "--data-fraction must be a number in (0, 1] (e.g. 0.25), got {}",
        a.data_fraction
    );
    if let Some(url) = &a.endpoint {
        anyhow::ensure!(
            url.starts_with("ws://") || url.starts_with("wss://"),
            "--endpoint {url}: give a ws:// or wss:// URL (docs/remote-protocol.md)"
        );
    }
    if let Some(onnx) = &a.onnx {
        anyhow::ensure!(onnx.is_file(), "--onnx {}: no such file", onnx.display());
        let (mpath, _, man) =
            crate::common::evaluation::read_manifest(onnx, a.manifest.as_deref())?;
        anyhow::ensure!(
            man.task == task,
            "the manifest {} is for task `{}` but --task is `{task}`",
            mpath.display(),
            man.task
        );
        anyhow::ensure!(
            man.obs_type == obs_type,
            "the manifest {} says obs_type `{}` but --obs-type is `{obs_type}`",
            mpath.display(),
            man.obs_type
        );
        man.validate()
            .map_err(|e| anyhow::anyhow!("the manifest {}: {e}", mpath.display()))?;
    }
    Ok(())
}

pub(crate) fn client_of(a: &Args) -> anyhow::Result<d3il_server::client::Client> {
    let token = match a.token.clone() {
        Some(t) => t,
        None => std::env::var("D3IL_TOKEN").context(
            "give --token or set D3IL_TOKEN (mint one with `d3il token create --name <you>`)",
        )?,
    };
    Ok(d3il_server::client::Client::new(&a.server, Some(token))?)
}

pub fn run(a: Args) -> anyhow::Result<()> {
    if let Some(id) = a.cancel {
        let v = client_of(&a)?.cancel(id)?;
        println!(
            "submission {id} cancelled: status {}, what ran is kept (partial)",
            v["status"].as_str().unwrap_or("?")
        );
        return Ok(());
    }
    if let Some(id) = a.cancel_race {
        let v = client_of(&a)?.cancel_race(id)?;
        println!(
            "race {id} cancelled: status {}",
            v["status"].as_str().unwrap_or("?")
        );
        return Ok(());
    }
    let (Some(method), Some(task), Some(training_seed)) =
        (a.method.clone(), a.task.clone(), a.training_seed)
    else {
        anyhow::bail!("give --method, --task and --training-seed (or --cancel ID, --cancel-race ID, or --race A B)");
    };
    anyhow::ensure!(
        a.onnx.is_some() || a.endpoint.is_some(),
        "give --onnx FILE (its manifest next to it as FILE.json, or --manifest) or --endpoint URL"
    );
    check_locally(&a, &task, training_seed)?;
    let client = client_of(&a)?;
    let mut fields: Vec<(&str, String)> = vec![
        ("method", method),
        ("task", task),
        ("obs_type", a.obs_type.clone()),
        ("training_seed", training_seed.to_string()),
        ("data_fraction", a.data_fraction.to_string()),
        ("protocol", a.protocol.clone()),
    ];
    for (k, v) in [
        ("history", a.history.map(|h| h.to_string())),
        ("backbone", a.backbone.clone()),
        ("prediction", a.prediction.clone()),
        ("diversity", a.diversity.clone()),
        ("code_url", a.code_url.clone()),
        ("paper_url", a.paper_url.clone()),
        ("description", a.description.clone()),
        ("endpoint_url", a.endpoint.clone()),
        ("suite", a.suite.map(|s| s.to_string())),
    ] {
        if let Some(v) = v {
            fields.push((k, v));
        }
    }
    if a.endpoint.is_some() {
        if let Some(secret) =
            d3il_protocol::EndpointSecret::from_env().map_err(anyhow::Error::msg)?
        {
            fields.push(("endpoint_secret", secret.expose().to_string()));
        }
    }
    if let Some(onnx) = &a.onnx {
        let (_, text, _) = crate::common::evaluation::read_manifest(onnx, a.manifest.as_deref())?;
        fields.push(("manifest", text));
    } else if let Some(m) = &a.manifest {
        let text = std::fs::read_to_string(m)
            .with_context(|| format!("cannot read the manifest {}", m.display()))?;
        fields.push(("manifest", text));
    }
    let created = client.submit(&fields, a.onnx.as_deref())?;
    let id = created["id"]
        .as_i64()
        .context("the server's answer has no submission id")?;
    println!(
        "submission {id} accepted: {}{}",
        a.server.trim_end_matches('/'),
        created["url"].as_str().unwrap_or("")
    );
    if let Some(q) = created["quota"]["summary"].as_str() {
        eprintln!("quota: {q}");
    }
    if !a.wait {
        return Ok(());
    }
    let mut last = String::new();
    let done = client.wait(id, Duration::from_secs(a.timeout), |v| {
        let line = progress_line(v);
        if line != last {
            eprintln!("{line}");
            last = line;
        }
    })?;
    if a.json {
        println!("{}", serde_json::to_string_pretty(&done)?);
    }
    anyhow::ensure!(
        done["status"] == "completed",
        "the evaluation failed: {}",
        done["error"]
    );
    if !a.json {
        print!(
            "{}",
            d3il_tables::summary::metrics_table(&result_of(&done)?)
        );
        if a.suite.is_some() {
            // The robustness tables, as `d3il eval --suite robustness`.
            let doc = client.get(&format!(
                "/api/v1/submissions/{id}/robustness?rollouts=false"
            ))?;
            let doc: d3il_protocol::robustness::RobustnessResult = serde_json::from_value(doc)
                .context("the server's robustness document does not parse")?;
            print!("{}", crate::common::text::robustness(&doc));
        }
    }
    Ok(())
}

/// One line of `--wait`'s progress from the server's submission document:
/// the status, then the rollouts done of the total once the worker has said
/// how many there are (until then the total is 0, and "0/0" would read as an
/// empty evaluation), or the queue position while queued.
fn progress_line(v: &serde_json::Value) -> String {
    let status = v["status"].as_str().unwrap_or("?");
    let p = &v["progress"];
    match (p["rollouts_done"].as_i64(), p["rollouts_total"].as_i64()) {
        (Some(done), Some(total)) if total > 0 => format!("{status} {done}/{total}"),
        _ => match v["queue_position"].as_i64() {
            Some(n) => format!("{status}, {n} ahead in the queue"),
            None if status == "running" => "running, starting".to_string(),
            None => status.to_string(),
        },
    }
}

/// The evaluation result inside the server's submission document
/// (`result`: metrics, protocol manifest, per-state and per-rollout records).
pub fn result_of(doc: &serde_json::Value) -> anyhow::Result<d3il_protocol::EvalResult> {
    let r = &doc["result"];
    let v = serde_json::json!({
        "manifest": r["protocol_manifest"],
        "metrics": r["metrics"],
        "per_context": r["per_context"],
        "rollouts": r["rollouts"],
        "rollouts_ended_unstable": r["rollouts_ended_unstable"].as_u64().unwrap_or(0),
    });
    serde_json::from_value(v).context(
        "the server's result document is not what this client expects; use --json to see it",
    )
}

#[cfg(test)]
mod tests {
    use super::progress_line;
    use serde_json::json;

    #[test]
    fn progress_lines_never_show_an_empty_total() {
        let doc = |status: &str, done: i64, total: i64, pos: Option<i64>| {
            json!({"status": status, "progress": {"rollouts_done": done, "rollouts_total": total},
                   "queue_position": pos})
        };
        assert_eq!(
            progress_line(&doc("queued", 0, 0, Some(2))),
            "queued, 2 ahead in the queue"
        );
        assert_eq!(
            progress_line(&doc("queued", 0, 0, Some(0))),
            "queued, 0 ahead in the queue"
        );
        assert_eq!(
            progress_line(&doc("running", 0, 0, None)),
            "running, starting"
        );
        assert_eq!(
            progress_line(&doc("running", 0, 480, None)),
            "running 0/480"
        );
        assert_eq!(
            progress_line(&doc("completed", 6, 6, None)),
            "completed 6/6"
        );
        assert_eq!(progress_line(&doc("failed", 0, 0, None)), "failed");
    }
}
