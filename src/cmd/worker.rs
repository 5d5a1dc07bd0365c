//! `d3il worker`: evaluate one job inside the sandbox (docs/sandbox.md).
//!
//! Reads one JSON job on stdin, confines itself (rlimits, network namespace,
//! landlock, seccomp) before anything from the submission is parsed, prints JSON
//! lines on stdout (`sandbox`, `progress`..., then `result` or `error`) and exits
//! with the codes in `d3il_protocol::exit_code`. Normally started by the server
//! or `d3il eval --sandbox` through `d3il_sandbox::run_worker`, not by hand.

use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Confine this process as for an ONNX job, probe that the confinement
    /// holds (no fork, exec, TCP, writes, foreign reads), print the mechanisms
    /// in force and exit (non-zero if a probe was not stopped).
    #[arg(long)]
    pub check_sandbox: bool,
    /// With --check-sandbox: print JSON instead of a table.
    #[arg(long, requires = "check_sandbox")]
    pub json: bool,
    /// With --check-sandbox: the assets directory a job would read.
    #[arg(long, default_value = "assets")]
    pub assets: PathBuf,
    /// Refuse jobs unless these mechanisms are active (comma-separated names as
    /// printed by --check-sandbox, or `all`). Default: $D3IL_SANDBOX_REQUIRE.
    #[arg(long, value_delimiter = ',')]
    pub require: Vec<String>,
    /// With --check-sandbox: confine with these limits (JSON of
    /// `d3il_protocol::Limits`, as the server passes its configured ones)
    /// instead of the defaults.
    #[arg(long, requires = "check_sandbox", hide = true)]
    pub limits_json: Option<String>,
    /// Test-only misbehaving evaluation (see d3il_sandbox::selftest).
    #[arg(long, hide = true)]
    pub self_test: Option<String>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.check_sandbox {
        return check(&args);
    }
    let mut require = args.require.clone();
    if require.is_empty() {
        if let Ok(v) = std::env::var("D3IL_SANDBOX_REQUIRE") {
            require = v
                .split(',')
                .filter(|s| !s.is_empty())
                .map(str::to_string)
                .collect();
        }
    }
    let opts = d3il_sandbox::WorkerOptions { require };
    let code = match args.self_test.as_deref() {
        Some(mode) => {
            if let Some(code) = d3il_sandbox::selftest::before_worker(mode) {
                std::process::exit(code);
            }
            d3il_sandbox::worker_main(&opts, |job, progress| {
                let mut counts =
                    |d: usize, t: usize| progress(&d3il_protocol::Progress::counts(d, t));
                d3il_sandbox::selftest::evaluate(mode, job, &mut counts).map(Into::into)
            })
        }
        None => d3il_sandbox::worker_main(&opts, |job, progress| {
            d3il_evaluator::job::run_job_or_shard(job, progress)
        }),
    };
    std::process::exit(code);
}

fn check(args: &Args) -> anyhow::Result<()> {
    let limits: d3il_protocol::Limits = match &args.limits_json {
        Some(j) => serde_json::from_str(j)
            .map_err(|e| anyhow::anyhow!("--limits-json is not a limits document: {e}"))?,
        None => Default::default(),
    };
    let mechanisms = d3il_sandbox::check_sandbox_with(&args.assets, &limits)
        .map_err(|e| anyhow::anyhow!("the sandbox could not be set up: {e}"))?;
    if args.json {
        println!("{}", serde_json::to_string_pretty(&mechanisms)?);
    } else {
        for m in &mechanisms {
            println!(
                "{:<28} {:<8} {}",
                m.name,
                if m.active { "active" } else { "INACTIVE" },
                m.detail
            );
        }
    }
    let breached: Vec<&str> = mechanisms
        .iter()
        .filter(|m| m.name.starts_with("probe:") && !m.active)
        .map(|m| m.name.as_str())
        .collect();
    if !breached.is_empty() {
        anyhow::bail!(
            "sandbox probes not stopped: {}; do not run untrusted submissions on this host",
            breached.join(", ")
        );
    }
    Ok(())
}
