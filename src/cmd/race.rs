//! `d3il race`: the sequential paired test of two policies (docs/sequential.md).
//!
//! * `d3il race --task T A B` races policies A and B on the same initial
//!   states in the same random order and stops when the test decides
//!   (`d3il_evaluator::eval::race`, the rule a server's race runs:
//!   `d3il submit --race A B`, `POST /api/v1/races`).
//! * `d3il race a.json b.json` replays the paired outcomes of two finished
//!   results in a seeded random order through the same test: when it would
//!   have stopped and what it would have saved.
//!
//! Both print the fixed-size comparison of the pairs used (the exact McNemar
//! test and its interval) as the race page does, with the same note that
//! neither holds after a data-dependent stop. (`d3il compare A B` is the
//! paired comparison of two finished results; `d3il compare --sequential`
//! is a deprecated alias of this command.)

use super::eval as eval_cmd;
use anyhow::{bail, Context};
use d3il_evaluator::eval::race::{self, Contender, RaceOptions, RaceReport};
use d3il_protocol::{EvalResult, TaskId};
use std::path::{Path, PathBuf};

#[derive(clap::Args, Clone)]
pub struct Args {
    /// Policy A, as `d3il eval --policy` takes it (ONNX file,
    /// `scripted:NAME`, `ws://…`); without `--task`, result A (`d3il eval
    /// --json a.json`) to replay.
    pub a: PathBuf,
    /// Policy B (or, without `--task`, result B, on the same task, protocol
    /// and initial states).
    pub b: PathBuf,
    /// Race the two policies on this task; without it, replay two results.
    #[arg(long)]
    pub task: Option<TaskId>,
    /// Level of the sequential test (two-sided).
    #[arg(long, default_value_t = 0.05)]
    pub alpha: f64,
    /// Also stop with "no difference larger than δ" when the confidence
    /// sequence of rate(A) − rate(B) lies inside (−δ, δ).
    #[arg(long)]
    pub delta: Option<f64>,
    /// Seed of the random order (and, with `--task`, of both policies' noise).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// With `--task`: `paper` or `quick`, the full size the race may run to.
    #[arg(long, default_value = "paper", requires = "task")]
    pub protocol: d3il_protocol::ProtocolKind,
    /// With `--task`: rollouts simulated at once per policy (fewer stop
    /// sooner after a decision, more run faster).
    #[arg(long, default_value_t = 8, requires = "task")]
    pub max_live: usize,
    /// Print the report as JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

/// Races two policies (`--task`) or replays two results.
pub fn run(args: &Args) -> anyhow::Result<()> {
    match args.task {
        Some(task) => race_policies(args, task),
        None => replay(args),
    }
}

/// The fixed-size comparison of the pairs a race (or replay) used, as the
/// race page shows it (`d3il_metrics::rate_difference::fixed_size_comparison`).
fn fixed_size_line(pairs_used: u64, discordant: (u64, u64), alpha: f64) -> String {
    d3il_metrics::rate_difference::fixed_size_comparison(pairs_used, discordant, alpha).line()
}

fn load(path: &Path) -> anyhow::Result<EvalResult> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| {
        format!(
            "{} is not an evaluation result; pass files written by `d3il eval --json FILE` (or race two policies with --task)",
            path.display()
        )
    })
}

fn replay(args: &Args) -> anyhow::Result<()> {
    d3il_protocol::race::check_race_params(args.alpha, args.delta)
        .map_err(|e| anyhow::anyhow!("--{}", e.message))?;
    let (a, b) = (load(&args.a)?, load(&args.b)?);
    let (pairs, per_state) = d3il_metrics::sequential::paired_outcomes_per_unit(&a, &b)?;
    let r = d3il_metrics::sequential::replay(&pairs, args.alpha, args.delta, args.seed);
    if args.json {
        let mut v = serde_json::to_value(&r)?;
        v["pair"] = (if per_state {
            "initial state"
        } else {
            "rollout"
        })
        .into();
        println!("{}", serde_json::to_string_pretty(&v)?);
    } else {
        if per_state {
            println!(
                "both policies did the same in every rollout of each initial state (deterministic): one pair per initial state"
            );
        }
        print!("{}", render_replay(&r));
    }
    Ok(())
}

/// The replay as plain text; its last line says what was saved.
pub fn render_replay(r: &d3il_metrics::sequential::Replay) -> String {
    let mut s = format!(
        "race replayed: A vs B in random order (seed {}), alpha {}{}\n",
        r.seed,
        r.alpha,
        r.delta
            .map(|d| format!(", margin δ {d}"))
            .unwrap_or_default()
    );
    s += &format!(
        "success rate over all {} pairs: A {:.3}, B {:.3}\n",
        r.pairs_total, r.rate_a, r.rate_b
    );
    match (&r.decision, r.decided_at) {
        (Some(d), Some(at)) => s += &format!("decision: {d} at pair {at} of {}\n", r.pairs_total),
        _ => {
            s += &format!(
                "decision: none after all {} pairs (the fixed-size test used the same pairs)\n",
                r.pairs_total
            )
        }
    }
    s += &format!(
        "e-value {:.3}, anytime-valid p-value {:.4}; discordant pairs so far: A won {}, B won {}\n",
        r.e_value, r.p_value, r.discordant.0, r.discordant.1
    );
    s += &d3il_metrics::horizon::rule_line(r.alpha, r.pairs_total as usize);
    s.push('\n');
    s += &d3il_metrics::horizon::decided_by(r.alpha, r.pairs_total as usize, r.decision.as_deref());
    s += ".\n";
    if let Some((lo, hi)) = r.difference_interval {
        s += &format!("confidence sequence of A − B: {lo:+.3} – {hi:+.3}\n");
    }
    s += &fixed_size_line(r.pairs_used, r.discordant, r.alpha);
    s += ".\n";
    s += &format!(
        "fixed-size paired test (exact sign test on all {} pairs): p = {:.4}\n",
        r.pairs_total, r.fixed_p_value
    );
    s += &format!(
        "rollouts used: {} of {} ({} per policy), ratio {:.3} of the fixed-size test\n",
        2 * r.pairs_used,
        2 * r.pairs_total,
        r.pairs_used,
        r.pairs_used as f64 / r.pairs_total.max(1) as f64
    );
    s
}

/// `d3il eval`'s arguments for one side: the same policy forms and checks.
#[derive(clap::Parser)]
struct EvalCli {
    #[command(flatten)]
    args: eval_cmd::Args,
}

fn side(args: &Args, task: TaskId, policy: &Path) -> anyhow::Result<eval_cmd::Args> {
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

fn race_policies(args: &Args, task: TaskId) -> anyhow::Result<()> {
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
pub fn render(r: &RaceReport, a: &Path, b: &Path) -> String {
    let mut s = format!(
        "race on {} ({} protocol, seed {}), alpha {}{}\nA: {}\nB: {}\n",
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
    s += &fixed_size_line(r.pairs_used, r.discordant, r.alpha);
    s += ".\n";
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

#[cfg(test)]
mod tests {
    #[test]
    fn the_replay_says_when_and_what_it_decided_and_what_it_saved() {
        let mut pairs = vec![(true, false); 40];
        pairs.extend([(false, true); 5]);
        pairs.extend([(true, true); 155]);
        let r = d3il_metrics::sequential::replay(&pairs, 0.05, None, 3);
        let text = super::render_replay(&r);
        let at = r.decided_at.unwrap();
        assert!(
            text.contains(&format!("decision: A better at pair {at} of 200")),
            "{text}"
        );
        assert!(
            text.contains(&format!("rollouts used: {} of 400", 2 * at)),
            "{text}"
        );
        assert!(text.contains("anytime-valid p-value"), "{text}");
        let none = d3il_metrics::sequential::replay(&[(true, true); 30], 0.05, Some(0.5), 0);
        let text = super::render_replay(&none);
        assert!(text.contains("decision: "), "{text}");
        assert!(text.contains("confidence sequence of A − B"), "{text}");
    }

    /// The replay prints the race page's fixed-size comparison of the
    /// pairs used: the exact McNemar interval and p-value, and the note
    /// that neither holds after the data-dependent stop.
    #[test]
    fn the_replay_prints_the_fixed_size_comparison_the_race_page_shows() {
        let mut pairs = vec![(true, false); 40];
        pairs.extend([(false, true); 5]);
        pairs.extend([(true, true); 155]);
        let r = d3il_metrics::sequential::replay(&pairs, 0.05, None, 3);
        let text = super::render_replay(&r);
        let f = d3il_metrics::rate_difference::ExactMcNemar::new(
            r.pairs_used as usize,
            r.discordant.0,
            r.discordant.1,
        )
        .paired_interval(0.95);
        let i = f.interval.expect("an interval");
        assert!(
            text.contains(&format!(
                "Fixed-size comparison of the {} pairs used: A − B {:+.3}, 95 % interval {:.3}–{:.3}",
                r.pairs_used, f.estimate, i.low, i.high
            )),
            "{text}"
        );
        assert!(
            text.contains(&format!("exact McNemar p-value {:.4}", f.p_value)),
            "{text}"
        );
        assert!(
            text.contains("neither is valid after the race's data-dependent stop"),
            "{text}"
        );
    }
}
