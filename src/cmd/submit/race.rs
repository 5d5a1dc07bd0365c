//! `d3il submit --race A B`: a race of two submissions on the server
//! (`POST /api/v1/races`). It talks to the server as
//! `d3il submit` does (same --server, --token, --wait, --json); the race
//! itself is `d3il_evaluator::eval::race`, run by a worker, the same rule as
//! `d3il race --task T A B`; the report prints the same way.

use super::Args;
use anyhow::Context;
use d3il_protocol::race::RaceReport;
use d3il_server::client::Client;
use std::time::Duration;

/// `d3il submit --race A B`: the server and token from submit's flags.
pub fn run_from_submit(a: &Args, pair: &[i64]) -> anyhow::Result<()> {
    let [id_a, id_b] = pair else {
        anyhow::bail!("--race takes two submission ids: --race A B");
    };
    run(a, &super::client_of(a)?, *id_a, *id_b)
}

pub fn run(a: &Args, client: &Client, id_a: i64, id_b: i64) -> anyhow::Result<()> {
    let mut body = serde_json::json!({
        "a": id_a,
        "b": id_b,
        "alpha": a.alpha,
        "protocol": a.protocol,
    });
    if let Some(d) = a.delta {
        body["delta"] = d.into();
    }
    if let Some(t) = &a.task {
        body["task"] = t.clone().into();
    }
    let created = client.race(&body)?;
    let id = created["id"]
        .as_i64()
        .context("the server's answer has no race id")?;
    println!(
        "race {id} accepted: {}/races/{id}",
        a.server.trim_end_matches('/')
    );
    if !a.wait {
        return Ok(());
    }
    let mut last = String::new();
    let done = client.wait_race(id, Duration::from_secs(a.timeout), |v| {
        let l = &v["live"];
        let line = format!(
            "{} pairs of {} states, e-value {:.2}, anytime p {:.3}",
            l["pairs"].as_u64().unwrap_or(0),
            l["states_total"].as_u64().unwrap_or(0),
            l["e_value"].as_f64().unwrap_or(1.0),
            l["p_value"].as_f64().unwrap_or(1.0)
        );
        if line != last && !a.json {
            eprint!("\r{line}   ");
            last = line;
        }
    })?;
    if !a.json {
        eprintln!();
    }
    if done["status"] != "completed" {
        anyhow::bail!(
            "race {id} {}: {}",
            done["status"].as_str().unwrap_or("failed"),
            done["error"].as_str().unwrap_or("no reason given")
        );
    }
    if a.json {
        println!("{}", serde_json::to_string_pretty(&done)?);
        return Ok(());
    }
    let report: RaceReport = serde_json::from_value(done["report"].clone())
        .context("the race's report is not a race report")?;
    print!(
        "{}",
        crate::common::text::race(
            &report,
            std::path::Path::new(&format!("submission {id_a}")),
            std::path::Path::new(&format!("submission {id_b}"))
        )
    );
    Ok(())
}
