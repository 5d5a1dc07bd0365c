//! `d3il db backup|restore|check` (docs/ops.md).

use crate::common::flags::DbArgs;
use std::path::PathBuf;

/// `d3il db backup|restore|check` (docs/ops.md).
#[derive(clap::Args, Debug)]
pub struct Args {
    #[command(subcommand)]
    pub action: Action,
}

#[derive(clap::Subcommand, Debug)]
pub enum Action {
    /// Write one archive of the database (a consistent copy, taken while the server serves), the policy files its rows use and a manifest (row counts, sizes, sha256s).
    Backup {
        #[command(flatten)]
        db: DbArgs,
        /// The archive to write (a gzipped tar; written to FILE.partial, then renamed).
        #[arg(long)]
        out: PathBuf,
    },
    /// Restore an archive into an empty database and policy directory, checking every file against the manifest and the restored row counts.
    Restore {
        /// The archive `d3il db backup` wrote.
        #[arg(long = "in")]
        input: PathBuf,
        #[command(flatten)]
        db: DbArgs,
        /// Replace a database that already has tables (and add to a policy directory that has files). Stop the server first.
        #[arg(long)]
        force: bool,
    },
    /// Report the schema version, the database's integrity and the store's consistency (results, jobs, policy files); exits non-zero with what to fix.
    Check {
        #[command(flatten)]
        db: DbArgs,
    },
}

fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    Ok(tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?)
}

fn summary(m: &d3il_server::backup::Manifest) -> String {
    let n = |t: &str| m.tables.get(t).copied().unwrap_or(0);
    let bytes: u64 = m.policy_files.iter().map(|f| f.bytes).sum::<u64>() + m.database.bytes;
    format!(
        "schema version {}: {} submissions, {} results, {} rollouts, {} tokens, {} policy files ({:.1} MB in all)",
        m.schema_version,
        n("submissions"),
        n("results"),
        n("rollouts"),
        n("api_tokens"),
        m.policy_files.len(),
        bytes as f64 / 1e6
    )
}

pub fn run(args: Args) -> anyhow::Result<()> {
    use anyhow::Context;
    use d3il_server::backup;
    let rt = runtime()?;
    match args.action {
        Action::Backup { db, out } => {
            crate::common::check_output_path(&out, "--out")?;
            let done = rt
                .block_on(backup::backup(&db.db, db.policy_store.as_deref(), &out))
                .with_context(|| format!("cannot back up {}", db.db))?;
            for missing in &done.manifest.missing_policy_files {
                eprintln!("warning: not in the archive: {missing}");
            }
            println!(
                "backed up {} to {} ({})",
                db.db,
                done.out.display(),
                summary(&done.manifest)
            );
            Ok(())
        }
        Action::Restore { input, db, force } => {
            let m = rt
                .block_on(backup::restore(
                    &input,
                    &db.db,
                    db.policy_store.as_deref(),
                    force,
                ))
                .with_context(|| format!("cannot restore {} into {}", input.display(), db.db))?;
            println!(
                "restored {} into {} ({}); rows and files match the manifest",
                input.display(),
                db.db,
                summary(&m)
            );
            if m.schema_version < backup::latest_known(m.postgres) {
                println!(
                    "the next `d3il serve --db {}` upgrades it to schema version {}",
                    db.db,
                    backup::latest_known(m.postgres)
                );
            }
            Ok(())
        }
        Action::Check { db } => {
            let r = rt
                .block_on(backup::check::check(&db.db, db.policy_store.as_deref()))
                .with_context(|| format!("cannot check {}", db.db))?;
            for line in &r.ok {
                println!("ok: {line}");
            }
            for line in &r.notes {
                println!("note: {line}");
            }
            for line in &r.problems {
                println!("PROBLEM: {line}");
            }
            anyhow::ensure!(
                r.problems.is_empty(),
                "{} problem(s) in {} (above, each with what to do)",
                r.problems.len(),
                db.db
            );
            Ok(())
        }
    }
}
