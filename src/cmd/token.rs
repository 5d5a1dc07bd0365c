//! `d3il token create --name NAME [--admin]`: mint an API token (printed once;
//! only its hash is stored). `d3il token revoke TOKEN_OR_PREFIX`: revoke one.

use anyhow::Context;

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
        /// An operator's token: it may also open the admin page (`/admin`).
        #[arg(long)]
        admin: bool,
        #[command(flatten)]
        db: super::db::DbArgs,
    },
    /// Revoke a token: requests with it are refused from now on.
    Revoke {
        /// The whole token, or its first 13 characters (`d3il_` and 8 more).
        token: String,
        #[command(flatten)]
        db: super::db::DbArgs,
    },
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.action {
        Action::Create { name, admin, db } => {
            let name = name.trim().to_string();
            anyhow::ensure!(
                !name.is_empty() && name.chars().count() <= 64,
                "--name must be 1-64 characters"
            );
            let token = d3il_server::cli::create_token_blocking(
                &db.db,
                db.policy_store.as_deref(),
                &name,
                admin,
            )
            .with_context(|| format!("cannot create a token in {}", db.db))?;
            println!("{token}");
            let prefix = &token[..d3il_server::store::TOKEN_PREFIX_LEN];
            eprintln!(
                "{} token for `{name}` created (prefix {prefix}, for `d3il token revoke`); it is shown only this once. \
                 Use it as `Authorization: Bearer <token>` or `d3il submit --token`.",
                if admin { "Admin" } else { "API" }
            );
            Ok(())
        }
        Action::Revoke { token, db } => {
            let revoked =
                d3il_server::cli::revoke_token_blocking(&db.db, db.policy_store.as_deref(), &token)
                    .with_context(|| format!("cannot revoke a token in {}", db.db))?;
            if revoked.prefixes.is_empty() {
                eprintln!("that token was already revoked");
            } else {
                eprintln!("revoked {}", revoked.prefixes.join(", "));
            }
            Ok(())
        }
    }
}
