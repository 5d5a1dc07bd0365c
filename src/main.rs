//! `d3il`: the one binary. Each subcommand lives in `src/cmd/<name>.rs` and
//! exposes `Args` (clap) and `run(args) -> anyhow::Result<()>`.

use clap::{Parser, Subcommand};

mod cmd;

#[derive(Parser)]
#[command(name = "d3il", version, about = "D3IL leaderboard: evaluate imitation-learning policies on the D3IL benchmark")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Benchmarks that print ratios (physics, eval, render).
    Bench(cmd::bench::Args),
}

fn main() -> anyhow::Result<()> {
    let cli = Cli::parse();
    match cli.command {
        Command::Bench(a) => cmd::bench::run(a),
    }
}
