#[derive(clap::Args)]
pub struct Args {
    /// Which benchmark: physics
    pub which: String,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    anyhow::bail!("unknown benchmark `{}`", args.which)
}
