//! Golden-file snapshots of every table in every format, rendered from the
//! paper data alone. Compared byte for byte; `UPDATE_GOLDEN=1 cargo test -p
//! d3il-tables --test tables golden` rewrites them (review the diff before committing).

use d3il_protocol::{paper, ObsType};
use d3il_tables::{render_table, Format, SourceFilter, TableKind};
use std::path::PathBuf;

/// The tables the paper has, with the observation types it reports them for.
const TABLES: [(TableKind, ObsType); 5] = [
    (TableKind::Main, ObsType::State),
    (TableKind::Main, ObsType::Image),
    (TableKind::Datasize, ObsType::State),
    (TableKind::Posvel, ObsType::State),
    (TableKind::Prelim, ObsType::State),
];

fn golden_path(kind: TableKind, obs: ObsType, format: Format) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/golden")
        .join(format!("{kind}-{obs}.{}", format.extension()))
}

#[test]
fn every_table_and_format_matches_its_golden_file() {
    let cells = paper::load_embedded().cells();
    let update = std::env::var("UPDATE_GOLDEN").is_ok_and(|v| v == "1");
    let mut mismatches = Vec::new();
    for (kind, obs) in TABLES {
        for format in Format::ALL {
            let got = render_table(&cells, kind, obs, format, SourceFilter::Reported)
                .unwrap_or_else(|e| panic!("{kind} {obs} {format}: {e}"));
            let path = golden_path(kind, obs, format);
            if update {
                std::fs::write(&path, &got).expect("write golden file");
                continue;
            }
            let want = std::fs::read_to_string(&path).unwrap_or_else(|e| {
                panic!(
                    "{}: {e}; run with UPDATE_GOLDEN=1 to create it",
                    path.display()
                )
            });
            if got != want {
                mismatches.push(path.display().to_string());
            }
        }
    }
    assert!(
        mismatches.is_empty(),
        "output differs from golden files (rerun with UPDATE_GOLDEN=1 and review the diff): {mismatches:?}"
    );
}

#[test]
fn tables_the_paper_does_not_have_are_refused_with_a_hint() {
    let cells = paper::load_embedded().cells();
    let err = render_table(
        &cells,
        TableKind::Posvel,
        ObsType::Image,
        Format::Latex,
        SourceFilter::Reported,
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("--obs state"), "{err}");
    let err = render_table(
        &cells,
        TableKind::Main,
        ObsType::State,
        Format::Latex,
        SourceFilter::Evaluated,
    )
    .unwrap_err()
    .to_string();
    assert!(err.contains("--source reported"), "{err}");
}
