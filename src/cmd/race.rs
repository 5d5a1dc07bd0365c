//! `d3il compare --sequential --task T A B`: races two policies on the same
//! initial states in the same random order and stops when the anytime-valid
//! paired test decides (`d3il_evaluator::eval::race`, docs/sequential.md).

use super::compare::Args;
use super::eval as eval_cmd;
use anyhow::bail;
use d3il_evaluator::eval::race::{self, Contender, RaceOptions, RaceReport};
use d3il_protocol::TaskId;

/// `d3il eval`'s arguments for one side: the same policy forms and checks.
#[derive(clap::Parser)]
struct EvalCli {
    #[command(flatten)]
    args: eval_cmd::Args,
}

fn side(args: &Args, task: TaskId, policy: &std::path::Path) -> anyhow::Result<eval_cmd::Args> {
    let policy = policy.to_string_lossy().into_owned();
    let cli = <EvalCli as clap::Parser>::try_parse_from([
        "d3il eval".to_string(),
        "--task".into(),
        task.to_string(),
        "--policy".into(),
        policy.clone(),
        "--protocol".into(),
        args.protocol.as_str().into(),
        "--seed".into(),
        args.seed.to_string(),
        "--max-live".into(),
        args.max_live.to_string(),
    ])
    .map_err(|e| anyhow::anyhow!("policy {policy}: {e}"))?;
    Ok(cli.args)
}

pub fn run(args: &Args, task: TaskId) -> anyhow::Result<()> {
    let race_opts = RaceOptions {
        alpha: args.alpha,
        delta: args.delta,
    };
    race_opts.check()?;
    if args.max_live == 0 {
        bail!("--max-live must be at least 1");
    }
    let (args_a, args_b) = (side(args, task, &args.a)?, side(args, task, &args.b)?);
    let (job_a, job_b) = (eval_cmd::build_job(&args_a)?, eval_cmd::build_job(&args_b)?);
    if job_a.manifest.obs_type != job_b.manifest.obs_type {
        bail!(
            "A takes {} observations and B {}: a race runs both on the same task variant",
            job_a.manifest.obs_type,
            job_b.manifest.obs_type
        );
    }
    let (task_a, mut policy_a, info_a, opts) = eval_cmd::load_in_process(&args_a, &job_a)?;
    let (_, mut policy_b, info_b, _) = eval_cmd::load_in_process(&args_b, &job_b)?;
    let quiet = args.json;
    let report = race::race(
        &task_a,
        Contender {
            policy: policy_a.as_mut(),
            info: &info_a,
        },
        Contender {
            policy: policy_b.as_mut(),
            info: &info_b,
        },
        &opts,
        &race_opts,
        &mut |p| {
            if !quiet {
                eprint!(
                    "\r{}/{} initial states, {} pairs, e-value {:.2}, anytime p {:.3}   ",
                    p.states, p.states_total, p.pairs, p.e_value, p.p_value
                );
            }
        },
    )?;
    if !quiet {
        eprintln!();
    }
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        print!("{}", render(&report, &args.a, &args.b));
    }
    Ok(())
}

/// The race as plain text; its last line says what was saved.
pub fn render(r: &RaceReport, a: &std::path::Path, b: &std::path::Path) -> String {
    let mut s = format!(
        "sequential race on {} ({} protocol, seed {}), alpha {}{}\nA: {}\nB: {}\n",
        r.task,
        r.protocol.as_str(),
        r.seed,
        r.alpha,
        r.delta
            .map(|d| format!(", margin δ {d}"))
            .unwrap_or_default(),
        a.display(),
        b.display()
    );
    s += &format!("pairs: one per {}\n", r.pair);
    match (&r.decision, r.decided_at) {
        (Some(d), Some(at)) => {
            s += &format!(
                "decision: {d} at pair {at} (initial state {} of {})\n",
                r.states_used, r.states_full
            )
        }
        _ => {
            s += &format!(
                "decision: none after all {} initial states (the protocol's full size)\n",
                r.states_full
            )
        }
    }
    s += &format!(
        "e-value {:.3}, anytime-valid p-value {:.4}; discordant pairs: A won {}, B won {}\n",
        r.e_value, r.p_value, r.discordant.0, r.discordant.1
    );
    s += &d3il_metrics::horizon::rule_line(r.alpha, r.pairs_full as usize);
    s.push('\n');
    s += &d3il_metrics::horizon::decided_by(r.alpha, r.pairs_full as usize, r.decision.as_deref());
    s += ".\n";
    s += &format!(
        "success rate on the states used: A {:.3}, B {:.3}\n",
        r.rate_a, r.rate_b
    );
    if let Some((lo, hi)) = r.difference_interval {
        s += &format!("confidence sequence of A − B: {lo:+.3} – {hi:+.3}\n");
    }
    s += &format!(
        "fixed-size paired test: the protocol's {} rollouts ({} pairs){}\n",
        r.rollouts_full,
        r.pairs_full,
        match r.fixed_pairs_for_power_90 {
            Some(n) => format!(
                "; at the discordance observed, the exact sign test needs {n} pairs for 90 % power"
            ),
            None => String::new(),
        }
    );
    s += &format!(
        "rollouts used: {} of {} (ratio {:.3}); simulated {} in {:.1} s\n",
        r.rollouts_used,
        r.rollouts_full,
        r.rollouts_used as f64 / r.rollouts_full.max(1) as f64,
        r.rollouts_simulated,
        r.seconds
    );
    s
}
