//! `d3il tables`: regenerates the D3IL paper's result tables (LaTeX, Markdown,
//! CSV) and figures (SVG) from the leaderboard database. The
//! rendering lives in the `d3il-tables` crate; this file reads the store.

use anyhow::Context;
use d3il_protocol::ObsType;
use d3il_server::ops::Store;
use d3il_tables::{FigureKind, Format, SourceFilter, TableKind};
use std::path::PathBuf;

#[derive(clap::Args, Debug)]
#[command(group(clap::ArgGroup::new("what").required(true).args(["table", "figure"])))]
pub struct Args {
    /// Table to regenerate: main, datasize, posvel, prelim, robustness
    /// (methods × axes of the robustness track, by suite version) or zoo
    /// (the paper's methods trained here on our demonstrations: a table of
    /// their own, never ranked with the paper's rows).
    #[arg(long)]
    pub table: Option<TableArg>,
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
    #[command(flatten)]
    pub db: crate::common::flags::DbArgs,
    /// Output file (default: standard output).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Submission whose Avoiding rollouts to draw (for --figure avoiding-paths).
    #[arg(long)]
    pub submission: Option<i64>,
    /// `--table zoo` loads this zoo into the database first, as `d3il
    /// serve` does at start.
    #[command(flatten)]
    pub zoo: crate::common::flags::ZooArg,
}

/// `--table`: one of the paper's tables, or the robustness table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TableArg {
    Paper(TableKind),
    Robustness,
    Zoo,
}

impl std::str::FromStr for TableArg {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        if s.trim().eq_ignore_ascii_case("robustness") {
            return Ok(TableArg::Robustness);
        }
        if s.trim().eq_ignore_ascii_case("zoo") {
            return Ok(TableArg::Zoo);
        }
        s.parse()
            .map(TableArg::Paper)
            .map_err(|e: d3il_tables::TablesError| format!("{e}, robustness, zoo"))
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    // The arguments first, before the database is opened.
    if let Some(path) = &args.out {
        crate::common::check_output_path(path, "--out")?;
    }
    match (args.figure, args.submission) {
        (Some(FigureKind::AvoidingPaths), None) => anyhow::bail!(
            "--figure avoiding-paths draws the rollouts of one submission: pass --submission ID of an evaluated Avoiding submission"
        ),
        (Some(FigureKind::AvoidingPaths), Some(_)) | (_, None) => {}
        (_, Some(_)) => anyhow::bail!(
            "--submission goes with --figure avoiding-paths (the other tables and figures draw every result)"
        ),
    }
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
    let store = Store::connect(&args.db.db, args.db.policy_store.as_deref())
        .await
        .with_context(|| format!("opening the database {}", args.db.db))?;
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
    // No canary runs here: no row is called another build's.
    let cells = store
        .result_cells(None)
        .await
        .context("reading result cells")?;
    let methods = store.method_infos().await.context("reading methods")?;
    match (args.table, args.figure) {
        (Some(TableArg::Robustness), _) => robustness_table(&store, args).await,
        (Some(TableArg::Zoo), _) => {
            if let Some(dir) = args.zoo.dir() {
                let report = d3il_server::zoo::load(&store, &dir)
                    .await
                    .with_context(|| format!("loading the zoo at {}", dir.display()))?;
                for (cell, why) in &report.skipped {
                    eprintln!("zoo cell {} skipped: {why}", cell.display());
                }
            }
            let rows = d3il_server::zoo::table_rows(&store)
                .await
                .context("reading the zoo's rows")?;
            Ok(d3il_tables::zoo::render_zoo(&rows, args.format)?)
        }
        (Some(TableArg::Paper(kind)), _) => Ok(d3il_tables::render_table_with(
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

/// `--table robustness`: every stored robustness result of `--obs`
/// policies, grouped by suite version (docs/robustness.md).
async fn robustness_table(store: &Store, args: &Args) -> anyhow::Result<String> {
    let entries: Vec<_> = store
        .robustness_rows(None)
        .await
        .context("reading robustness results")?
        .into_iter()
        .filter(|r| r.obs_type == args.obs)
        .map(|r| r.into_entry())
        .collect();
    Ok(d3il_tables::robustness::render_robustness(
        &entries,
        args.format,
    )?)
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
            table: Some(TableArg::Paper(TableKind::Main)),
            figure: None,
            obs: ObsType::State,
            format: Format::Latex,
            source: SourceFilter::Both,
            db: crate::common::flags::DbArgs {
                db: db.into(),
                policy_store: None,
            },
            out: Some(out),
            submission: None,
            zoo: crate::common::flags::ZooArg { zoo: None },
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
                a.table = Some(TableArg::Paper(kind));
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

    /// An evaluated Stacking submission shows as three rows whose success and
    /// entropy are each level's own (computed by d3il-metrics from rollouts in
    /// which the levels differ).
    #[test]
    fn evaluated_stacking_levels_have_their_own_entropies_in_the_tables() {
        use d3il_protocol::*;
        use d3il_server::ops::{NewMethod, NewPolicy, NewSubmission};
        let dir = scratch("stacking");
        let db = dir.join("d3il.sqlite");
        // Context 0: gbr, rgb stacked; gb, bg two registered; r one; none.
        // Context 1: rbg, rbg stacked; gr two; b one (the fixture's rollouts).
        let outcomes = d3il_test_support::stacking_outcomes();
        let ev = d3il_metrics::evaluate(
            TaskId::Stacking,
            &outcomes,
            2.0,
            &d3il_metrics::Bootstrap::default(),
        )
        .unwrap();
        let levels = ev.metrics.stacking_levels.unwrap();
        let result = EvalResult {
            manifest: ProtocolManifest {
                initial_states: "stacking-v2.json".into(),
                n_contexts: 2,
                rollouts_per_context: 6,
                max_steps: 1000,
                ..d3il_test_support::test_manifest(TaskId::Stacking, ProtocolKind::Paper)
            },
            metrics: ev.metrics.clone(),
            per_context: ev.per_context,
            rollouts: vec![],
            rollouts_ended_unstable: 0,
        };
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        rt.block_on(async {
            let store = Store::open(&db).await.unwrap();
            let m = store
                .ensure_method(
                    &NewMethod {
                        name: "Stack-X".into(),
                        ..Default::default()
                    },
                    None,
                )
                .await
                .unwrap();
            let sub = store
                .create_submission(
                    &NewSubmission {
                        method_id: m.id,
                        submitter_id: None,
                        task: TaskId::Stacking,
                        obs_type: ObsType::State,
                        training_seed: 0,
                        data_fraction: 1.0,
                        protocol: ProtocolKind::Paper,
                        policy: NewPolicy::Remote {
                            url: "ws://127.0.0.1:1/".into(),
                            secret: None,
                        },
                        manifest_json: "{}".into(),
                        simulated_once: None,
                    },
                    3,
                )
                .await
                .unwrap();
            let claimed = store.claim_job("test", 60).await.unwrap().unwrap();
            store
                .complete_job(claimed.job.id, sub, &result, &[])
                .await
                .unwrap();
        });
        let out = dir.join("main.csv");
        let mut a = args(db, out.clone());
        a.format = Format::Csv;
        a.source = SourceFilter::Evaluated;
        run(a).expect("d3il tables");
        let csv = std::fs::read_to_string(&out).unwrap();
        // Long format: one line per (task, metric) value.
        let header: Vec<&str> = csv.lines().next().unwrap().split(',').collect();
        let col = |name: &str| {
            header
                .iter()
                .position(|h| *h == name)
                .unwrap_or_else(|| panic!("no column {name} in {header:?}"))
        };
        let (method, task, metric, mean) = (col("method"), col("task"), col("metric"), col("mean"));
        let value = |title: &str, what: &str| -> f64 {
            csv.lines()
                .map(|l| l.split(',').collect::<Vec<_>>())
                .find(|f| f[method] == "Stack-X" && f[task] == title && f[metric] == what)
                .unwrap_or_else(|| panic!("no {title} {what} in\n{csv}"))[mean]
                .parse()
                .unwrap()
        };
        let mut seen = vec![];
        for (k, l) in levels.iter().enumerate() {
            let title = format!("Stacking-{} (T5)", k + 1);
            let s = value(&title, "success_rate");
            let e = value(&title, "entropy");
            // The tables print three decimals.
            assert!((s - l.success_rate.value).abs() < 5e-4, "{title}: {s}");
            assert!(
                (e - l.conditional_entropy.value).abs() < 5e-4,
                "{title}: {e}"
            );
            seen.push(e);
        }
        assert!(seen[0] != seen[1] && seen[1] != seen[2], "{seen:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }
}
