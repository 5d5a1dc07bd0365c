//! `d3il`: the one binary. Each subcommand lives in `src/cmd/<name>.rs` and
//! exposes `Args` (clap) and `run(args) -> anyhow::Result<()>`, except the
//! benchmarks (`d3il bench`, `src/bench/`); what several of them share is in
//! `src/common/`.

#![forbid(unsafe_code)]

use clap::{Parser, Subcommand};

mod bench;
mod cmd;
mod common;

#[derive(Parser)]
#[command(
    name = "d3il",
    version,
    about = "D3IL leaderboard: evaluate imitation-learning policies on the D3IL benchmark"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

// Parsed once per process; boxing the larger argument structs buys nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Subcommand)]
enum Command {
    /// Benchmarks that print ratios (physics, eval, render).
    Bench(bench::Args),
    /// Paired comparison of two `d3il eval --json` results on the same initial states (difference, interval, p-value).
    Compare(cmd::compare::Args),
    /// Generate or verify the fixed initial-state sets.
    Contexts(cmd::contexts::Args),
    /// Back up, restore and check the leaderboard's database and policy files (docs/ops.md).
    Db(cmd::db::Args),
    /// Record the scripted experts on training initial states in the D3IL reference code's dataset format (docs/demos.md).
    Demos(cmd::demos::Args),
    /// Evaluate a policy (ONNX file, ws:// or wss:// endpoint, or scripted) on a task and print the D3IL metrics.
    Eval(cmd::eval::Args),
    /// How closely this simulator follows the original D3IL one: the fidelity report (Markdown or JSON).
    Fidelity(cmd::fidelity::Args),
    /// Recompute the intervals of result or robustness documents made under earlier interval rules and print what moved (docs/intervals.md).
    Intervals(cmd::intervals::Args),
    /// Run an ONNX policy on given inputs after the evaluator's admission and print its raw actions as JSON (an exporter's check).
    Infer(cmd::infer::Args),
    /// Merge the part files of a sharded `d3il eval --shard K/N` into one result (docs/cluster.md).
    Merge(cmd::merge::Args),
    /// Race two policies on a task (`--task`), stopping when the sequential paired test decides, or replay two results through that test (docs/sequential.md).
    Race(cmd::race::Args),
    /// Render what an image policy sees (both 96x96 cameras) to a PNG.
    Render(cmd::render::Args),
    /// Replay an episode open-loop from policy-level actions and print JSON.
    Replay(cmd::replay::Args),
    /// The drift canary: re-run the committed canary set, print what still
    /// matches and this build's physics fingerprint; fail on drift.
    Verify(cmd::verify::Args),
    /// Regenerate the paper's result tables (LaTeX/Markdown/CSV) and figures (SVG) from the database.
    Tables(cmd::tables::Args),
    /// Run the leaderboard web service (pages, plots, JSON API, worker pool).
    Serve(cmd::serve::Args),
    /// Manage API tokens (`d3il token create --name NAME`).
    Token(cmd::token::Args),
    /// Submit a policy to a leaderboard server.
    Submit(cmd::submit::Args),
    /// Evaluate one job from stdin inside the sandbox (started by the server; see docs/sandbox.md).
    Worker(cmd::worker::Args),
    /// Run a worker host: only the worker pool, on a PostgreSQL queue shared with `d3il serve` (docs/cluster.md).
    Workers(cmd::workers::Args),
    /// The zoo: check its cells against their provenance, or re-evaluate them with this build and write what moved (docs/zoo.md).
    Zoo(cmd::zoo::Args),
}

fn main() -> anyhow::Result<()> {
    // Before any thread exists: setting the environment later would race
    // with other threads reading it.
    d3il_evaluator::mujoco::set_llvmpipe_defaults();
    let cli = Cli::parse();
    match cli.command {
        Command::Bench(a) => bench::run(a),
        Command::Compare(a) if a.sequential => {
            eprintln!("note: `d3il compare --sequential` is deprecated; it is `d3il race` (the same arguments without --sequential)");
            cmd::race::run(&race_args_of(&a))
        }
        Command::Compare(a) => cmd::compare::run(a),
        Command::Race(a) => cmd::race::run(&a),
        Command::Contexts(a) => cmd::contexts::run(a),
        Command::Db(a) => cmd::db::run(a),
        Command::Demos(a) => cmd::demos::run(a),
        Command::Infer(a) => cmd::infer::run(a),
        Command::Intervals(a) => cmd::intervals::run(a),
        Command::Merge(a) => cmd::merge::run(a),
        Command::Render(a) => cmd::render::run(a),
        Command::Replay(a) => cmd::replay::run(a),
        Command::Verify(a) => cmd::verify::run(a),
        Command::Eval(a) => match a.suite {
            Some(suite) => cmd::robustness::run(&a, suite),
            None => cmd::eval::run(a),
        },
        Command::Fidelity(a) => cmd::fidelity::run(a),
        Command::Tables(a) => cmd::tables::run(a),
        Command::Serve(a) => cmd::serve::run(a),
        Command::Token(a) => cmd::token::run(a),
        // `d3il submit --race A B` races two submissions on the server
        // (cmd::submit::race, which reads submit's flags).
        Command::Submit(a) => match a.race.clone() {
            Some(pair) if a.cancel.is_none() => cmd::submit::race::run_from_submit(&a, &pair),
            _ => cmd::submit::run(a),
        },
        Command::Worker(a) => cmd::worker::run(a),
        Command::Workers(a) => cmd::workers::run(a),
        Command::Zoo(a) => cmd::zoo::run(a),
    }
}

/// `d3il compare --sequential …` as the `d3il race …` it stands for.
fn race_args_of(c: &cmd::compare::Args) -> cmd::race::Args {
    cmd::race::Args {
        a: c.a.clone(),
        b: c.b.clone(),
        task: c.task,
        alpha: c.alpha,
        delta: c.delta,
        seed: c.seed,
        protocol: c.protocol,
        max_live: c.max_live,
        json: c.json,
    }
}

#[cfg(test)]
mod tests {
    use clap::CommandFactory;

    /// Every option and argument of every subcommand says what it is for in
    /// `--help` (`eval --protocol`, `submit --training-seed`, ...
    /// had none).
    #[test]
    fn every_argument_has_help_text() {
        fn walk(cmd: &clap::Command, path: &str, missing: &mut Vec<String>) {
            for arg in cmd.get_arguments() {
                let id = arg.get_id().as_str();
                if id == "help" || id == "version" {
                    continue;
                }
                if arg.get_help().is_none() && arg.get_long_help().is_none() {
                    missing.push(format!("{path} --{}", arg.get_long().unwrap_or(id)));
                }
            }
            for sub in cmd.get_subcommands() {
                if sub.get_about().is_none() && sub.get_long_about().is_none() {
                    missing.push(format!("{path} {} (the subcommand itself)", sub.get_name()));
                }
                walk(sub, &format!("{path} {}", sub.get_name()), missing);
            }
        }
        let cmd = super::Cli::command();
        cmd.clone().debug_assert();
        let mut missing = vec![];
        walk(&cmd, "d3il", &mut missing);
        assert!(missing.is_empty(), "arguments without help: {missing:#?}");
    }
}
