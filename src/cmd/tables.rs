//! `d3il tables`: regenerates the D3IL paper's result tables (LaTeX, Markdown,
//! CSV) and figures (SVG) from the leaderboard database (issue 8). The
//! rendering lives in the `d3il-tables` crate; this file reads the store.

use anyhow::Context;
use d3il_protocol::ObsType;
use d3il_server::store::Store;
use d3il_tables::{FigureKind, Format, MethodInfo, SourceFilter, TableKind};
use std::collections::BTreeMap;
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(group(clap::ArgGroup::new("what").required(true).args(["table", "figure"])))]
pub struct Args {
    /// Table to regenerate: main, datasize, posvel, prelim.
    #[arg(long)]
    pub table: Option<TableKind>,
    /// Figure to draw as SVG: datasize, pareto, avoiding-paths.
    #[arg(long)]
    pub figure: Option<FigureKind>,
    /// Observation type of the policies: state or image.
    #[arg(long, default_value = "state")]
    pub obs: ObsType,
    /// Table format: latex, markdown, csv.
    #[arg(long, default_value = "latex")]
    pub format: Format,
    /// Rows to show: the paper's reported numbers, our evaluations, or both.
    #[arg(long, default_value = "both")]
    pub source: SourceFilter,
    /// SQLite database of the server (created with the paper's results if missing).
    #[arg(long, default_value = "d3il.sqlite")]
    pub db: PathBuf,
    /// Output file (default: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Submission whose Avoiding rollouts to draw (for --figure avoiding-paths).
    #[arg(long)]
    pub submission: Option<i64>,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // The store is async (sqlx); this command needs nothing more than a
    // single-threaded runtime for the few queries it makes.
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .context("starting the async runtime")?;
    let output = rt.block_on(render(&args))?;
    match &args.out {
        Some(path) => {
            std::fs::write(path, output).with_context(|| format!("writing {}", path.display()))?;
            eprintln!("wrote {}", path.display());
        }
        None => print!("{output}"),
    }
    Ok(())
}

async fn render(args: &Args) -> anyhow::Result<String> {
    let store = Store::open(&args.db)
        .await
        .with_context(|| format!("opening the database {}", args.db.display()))?;
    if let Some(FigureKind::AvoidingPaths) = args.figure {
        let id = args.submission.context(
            "--figure avoiding-paths draws the rollouts of one submission: pass --submission ID of an evaluated Avoiding submission",
        )?;
        let paths = store
            .avoiding_paths(id)
            .await
            .with_context(|| format!("reading the rollout paths of submission {id}"))?;
        let title = format!("Avoiding: end-effector paths of submission {id}");
        return Ok(d3il_tables::render_avoiding_paths(&paths, &title)?);
    }
    let cells = store.result_cells().await.context("reading result cells")?;
    let methods = method_infos(&store).await?;
    match (args.table, args.figure) {
        (Some(kind), _) => Ok(d3il_tables::render_table_with(
            &cells,
            kind,
            args.obs,
            args.format,
            args.source,
            &methods,
        )?),
        (None, Some(kind)) => Ok(d3il_tables::render_figure(
            &cells,
            kind,
            args.obs,
            args.source,
            &methods,
        )?),
        // clap's required group guarantees one of the two.
        (None, None) => anyhow::bail!("pass --table or --figure"),
    }
}

/// History and action chunking of the methods submitters registered (the
/// paper's own methods use the paper's properties inside d3il-tables). The
/// method's free-text `prediction` counts as action chunking when it mentions
/// a chunk; a method without a history is treated as history-free.
async fn method_infos(store: &Store) -> anyhow::Result<BTreeMap<String, MethodInfo>> {
    let rows = store.methods().await.context("reading methods")?;
    Ok(rows
        .into_iter()
        .map(|m| {
            let info = MethodInfo {
                history: m.history.and_then(|h| u32::try_from(h).ok()).unwrap_or(1),
                action_chunking: m
                    .prediction
                    .as_deref()
                    .is_some_and(|p| p.to_ascii_lowercase().contains("chunk")),
            };
            (m.name, info)
        })
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("d3il-tables-cli-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).expect("scratch dir");
        dir
    }

    fn args(db: PathBuf, out: PathBuf) -> Args {
        Args {
            table: Some(TableKind::Main),
            figure: None,
            obs: ObsType::State,
            format: Format::Latex,
            source: SourceFilter::Both,
            db,
            out: Some(out),
            submission: None,
        }
    }

    /// A fresh database (created by the store with the paper's results) gives
    /// exactly the golden main state table, twice in a row.
    #[test]
    fn fresh_database_reproduces_the_papers_main_state_table() {
        let dir = scratch("fresh");
        let db = dir.join("d3il.sqlite");
        let golden = std::fs::read_to_string(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/tables/tests/golden/main-state.tex"
        ))
        .expect("golden file");
        for round in 0..2 {
            let out = dir.join(format!("main-{round}.tex"));
            run(args(db.clone(), out.clone())).expect("d3il tables");
            let got = std::fs::read_to_string(&out).expect("output");
            // The golden file was rendered with --source reported; with no
            // evaluations, `both` differs only in the header comment.
            assert_eq!(
                got.replacen("both results", "reported results", 1),
                golden,
                "round {round}"
            );
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn every_table_format_and_figure_renders_from_the_database() {
        let dir = scratch("all");
        let db = dir.join("d3il.sqlite");
        for kind in TableKind::ALL {
            for format in Format::ALL {
                let out = dir.join(format!("{kind}.{}", format.extension()));
                let mut a = args(db.clone(), out.clone());
                a.table = Some(kind);
                a.format = format;
                run(a).unwrap_or_else(|e| panic!("{kind} {format}: {e:#}"));
                assert!(std::fs::metadata(&out).expect("written").len() > 0);
            }
        }
        for figure in [FigureKind::Datasize, FigureKind::Pareto] {
            let out = dir.join(format!("{figure}.svg"));
            let mut a = args(db.clone(), out.clone());
            a.table = None;
            a.figure = Some(figure);
            run(a).unwrap_or_else(|e| panic!("{figure}: {e:#}"));
            let svg = std::fs::read_to_string(&out).expect("svg");
            assert!(svg.starts_with("<svg") && svg.contains("BESO"));
        }
        // The paths figure needs a submission; without one the message says so.
        let mut a = args(db.clone(), dir.join("paths.svg"));
        a.table = None;
        a.figure = Some(FigureKind::AvoidingPaths);
        let err = format!("{:#}", run(a).unwrap_err());
        assert!(err.contains("--submission"), "{err}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
