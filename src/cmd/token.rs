//! `d3il token create --name NAME`: mint an API token (printed once; only its hash is stored).

use anyhow::Context;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    pub action: Action,
}

#[derive(clap::Subcommand, Debug)]
pub enum Action {
    /// Create a token for a submitter (created if new).
    Create {
        /// Submitter name shown on submissions.
        #[arg(long)]
        name: String,
        /// SQLite database of the server.
        #[arg(long, default_value = "d3il.sqlite")]
        db: PathBuf,
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.action {
        Action::Create { name, db } => {
            let name = name.trim().to_string();
            anyhow::ensure!(
                !name.is_empty() && name.chars().count() <= 64,
                "--name must be 1-64 characters"
            );
            let token = d3il_server::cli::create_token_blocking(&db, &name)
                .with_context(|| format!("cannot create a token in {}", db.display()))?;
            println!("{token}");
            eprintln!("Token for `{name}` created; it is shown only this once. Use it as `Authorization: Bearer <token>` or `d3il submit --token`.");
            Ok(())
        }
    }
}
