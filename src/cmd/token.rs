//! `d3il token create --name NAME [--admin]`: mint an API token (printed once;
//! only its hash is stored). `d3il token revoke TOKEN_OR_PREFIX`: revoke one.
//! `d3il token set-quota --name NAME --per-day N ...`: a submitter's quota
//! overrides. Revocations and quota changes go to the audit log.

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
        db: crate::common::flags::DbArgs,
    },
    /// Set a submitter's quota overrides (all its tokens share them); a
    /// limit left out, or `default`, is the server's (`d3il serve
    /// --quota-*`); 0 is no limit.
    SetQuota {
        /// Submitter name (as given to `d3il token create --name`).
        #[arg(long)]
        name: String,
        /// Submissions in any 24 hours: a number, 0 (no limit) or `default`.
        #[arg(long, value_parser = quota_value)]
        per_day: Option<QuotaValue>,
        /// Submissions in total.
        #[arg(long, value_parser = quota_value)]
        total: Option<QuotaValue>,
        /// Evaluations queued or running at once.
        #[arg(long, value_parser = quota_value)]
        concurrent: Option<QuotaValue>,
        #[command(flatten)]
        db: crate::common::flags::DbArgs,
    },
    /// Revoke a token: requests with it are refused from now on.
    Revoke {
        /// The whole token, or its first 13 characters (`d3il_` and 8 more).
        token: String,
        #[command(flatten)]
        db: crate::common::flags::DbArgs,
    },
}

/// A `--per-day`/`--total`/`--concurrent` value: None is `default`.
#[derive(Debug, Clone, Copy)]
pub struct QuotaValue(Option<i64>);

fn quota_value(s: &str) -> Result<QuotaValue, String> {
    if s == "default" {
        return Ok(QuotaValue(None));
    }
    s.parse::<i64>()
        .ok()
        .filter(|n| *n >= 0)
        .map(|n| QuotaValue(Some(n)))
        .ok_or_else(|| format!("`{s}` is not a quota: give a number (0: no limit) or `default`"))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match args.action {
        Action::SetQuota {
            name,
            per_day,
            total,
            concurrent,
            db,
        } => {
            let q = d3il_server::ops::QuotaOverrides {
                per_day: per_day.and_then(|v| v.0),
                total: total.and_then(|v| v.0),
                concurrent: concurrent.and_then(|v| v.0),
            };
            let entry = d3il_server::cli::set_quota_blocking(
                &db.db,
                db.policy_store.as_deref(),
                name.trim(),
                q,
            )
            .with_context(|| format!("cannot set the quota in {}", db.db))?;
            eprintln!("quota of `{}` set: {}", name.trim(), entry.detail);
            Ok(())
        }
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
            let prefix = &token[..d3il_server::ops::TOKEN_PREFIX_LEN];
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
