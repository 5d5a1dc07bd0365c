//! `d3il bench <which>`: benchmarks that print rates and the ratio the issue
//! tracks on their last line. Speed goals live here, never in tests.
//!
//! The benchmarks are a module of their own beside the commands (`src/cmd/`):
//! they use `crate::common` and the library crates, never a command's module,
//! and no command uses them. This module dispatches; each benchmark is a
//! submodule (`engine` holds the in-process ones: physics, eval, render,
//! agents).

use d3il_protocol::ProtocolKind;
use engine::{agents_bench, eval_bench, physics, render_bench, SMOKE_EVAL_STEPS};

mod chaos;
mod engine;
mod fixtures;
mod intervals;
mod procs;
mod robustness;
mod scale;
mod scripts;
mod sequential;
mod serve;
mod served_agent;
mod video;

/// Every benchmark `d3il bench` runs (its name on the command line is the
/// variant's in kebab case: `served-agent`). `tests/bench_smoke.rs` reads
/// this list from the binary and runs each one's smoke mode.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bench {
    /// Controlled env stepping against raw `mj_step` (Avoiding scene).
    Physics,
    /// A protocol's state evaluation with a BC-MLP-sized policy, batched and row by row.
    Eval,
    /// The two cameras' frames, and an image-based evaluation through the engine.
    Render,
    /// Every agent fixture (one per method family) at the evaluator's batch.
    Agents,
    /// The server under keep-alive readers while half-open connections attack it.
    Serve,
    /// A sharded paper-protocol evaluation on worker hosts and PostgreSQL.
    Scale,
    /// What replayable rollouts cost: traces' size, replay and video time.
    Video,
    /// Every scripted expert once per initial state of its task's fixed set.
    Scripts,
    /// The whole service under faults (workers and front ends killed).
    Chaos,
    /// The anytime-valid sequential paired test against the fixed-size one.
    Sequential,
    /// A reference agent served over the remote-endpoint protocol.
    ServedAgent,
    /// A robustness suite's cost per env step against a plain evaluation's.
    Robustness,
    /// Simulated coverage of every interval the service prints.
    Intervals,
}

#[derive(clap::Args)]
pub struct Args {
    /// Which benchmark.
    #[arg(value_enum)]
    pub which: Bench,
    /// A short run that only shows the bench still works (seconds, not
    /// minutes; its numbers mean little). `tests/bench_smoke.rs` runs every
    /// bench this way.
    #[arg(long)]
    pub smoke: bool,
    /// Env steps to run (physics, render).
    #[arg(long, default_value_t = 3000)]
    pub steps: usize,
    /// Protocol of `eval`, `scale` and `video` (paper: Aligning's 60 x 8 = 480 rollouts).
    #[arg(long, default_value = "paper")]
    pub protocol: ProtocolKind,
    /// Protocol of the image evaluation in `render` (quick: 3 initial states x 2 rollouts).
    #[arg(long, default_value = "quick")]
    pub render_protocol: ProtocolKind,
    /// Rollouts simulated at once in `eval` and `render` (the batch of `agents`
    /// and `served-agent`).
    #[arg(long, default_value_t = 96)]
    pub max_live: usize,
    /// Robot look in `render` (primitives: the scene the ratio goal is set
    /// for; meshes: the Panda meshes image evaluations use when present).
    #[arg(long, value_enum, default_value_t = crate::common::flags::Look::Primitives)]
    pub look: crate::common::flags::Look,
    /// Worker hosts of `scale` (each pinned to a core of its own).
    #[arg(long, default_value_t = 2)]
    pub hosts: usize,
    /// Shards the evaluation of `scale` is split into.
    #[arg(long, default_value_t = 6)]
    pub shards: usize,
}

pub fn run(mut args: Args) -> anyhow::Result<()> {
    if args.smoke {
        // Every bench's smallest honest run: the quick protocol, few steps.
        args.steps = args.steps.min(200);
        args.protocol = ProtocolKind::Quick;
        args.render_protocol = ProtocolKind::Quick;
        args.shards = args.hosts;
    }
    match args.which {
        Bench::Physics => physics(args.steps),
        Bench::Eval => eval_bench(
            args.protocol,
            args.max_live,
            args.smoke.then_some(SMOKE_EVAL_STEPS),
        ),
        Bench::Render => render_bench(
            args.steps,
            args.render_protocol,
            args.max_live,
            args.look,
            args.smoke,
        ),
        Bench::Agents => agents_bench(args.max_live, args.smoke),
        Bench::Serve => serve::run(args.smoke),
        Bench::Scale => scale::run(args.protocol, args.hosts, args.shards),
        Bench::Video => video::run(args.protocol),
        Bench::Scripts => scripts::run(args.smoke),
        Bench::Chaos => chaos::run(args.smoke),
        Bench::Sequential => sequential::run(args.smoke),
        Bench::ServedAgent => served_agent::run(args.smoke, args.max_live),
        Bench::Robustness => robustness::run(args.protocol, args.smoke.then_some(SMOKE_EVAL_STEPS)),
        Bench::Intervals => intervals::run(args.smoke),
    }
}
