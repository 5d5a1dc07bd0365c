//! `d3il tables --table robustness` from a database holding robustness
//! results (written as a worker stores them): one table per suite version,
//! ranked by overall score, methods aggregated over training seeds (mean ±
//! std, as the boards) with the rows per seed after them, in Markdown, LaTeX
//! and CSV; a database without any says what to do. A row whose scores come
//! from fewer than 30 initial states is labelled with its intervals'
//! measured coverage, in every format.

use crate::robustness_support;
use crate::EXE;
use d3il_test_support::first_states;
use d3il_test_support::server::*;
use robustness_support::{
    document, seed, seed_documents, three, three_and_a_second_seed, OTHER_SHA256,
};
use std::process::Command;

fn tables(db: &std::path::Path, format: &str) -> (bool, String, String) {
    let out = Command::new(EXE)
        .args([
            "tables",
            "--table",
            "robustness",
            "--format",
            format,
            "--db",
        ])
        .arg(db)
        .output()
        .expect("run d3il tables");
    (
        out.status.success(),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

#[test]
fn the_robustness_table_ranks_within_a_suite_version_in_every_format() {
    let dir = TempDir::new("robustness-tables");
    let db = dir.path().join("lb.sqlite");
    // An empty database: a clear error, not an empty table.
    let (ok, _, err) = tables(&db, "markdown");
    assert!(!ok);
    assert!(err.contains("suite=robustness"), "{err}");
    let ids = seed(&db, &three_and_a_second_seed());

    let (ok, md, err) = tables(&db, "markdown");
    assert!(ok, "{err}");
    // Two groups: the committed suite and the other version, never together.
    let groups: Vec<&str> = md.split("): suite ").skip(1).collect();
    assert_eq!(groups.len(), 2, "{md}");
    let (current, other) = if groups[0].contains(&OTHER_SHA256[..12]) {
        (groups[1], groups[0])
    } else {
        (groups[0], groups[1])
    };
    assert!(
        other.contains("Older-Suite") && !other.contains("Diverse"),
        "{md}"
    );
    assert!(!current.contains("Older-Suite"), "{md}");
    // Methods over seeds: Diverse's seeds 0 and 1 in one row, mean ± std.
    let diverse = current
        .find("| 1 | Diverse | 0, 1 | ")
        .expect("Diverse over its two seeds ranked 1");
    let line = current[diverse..].lines().next().unwrap();
    assert!(line.matches(" ± ").count() >= 6, "{line}");
    assert!(current.contains("| 2 | Narrow | 0 | "), "{md}");
    // The rows per seed after them; the diverse method keeps more of its
    // success: ranked first.
    assert!(current.contains("Diverse (seed 1)"), "{md}");
    let diverse = current
        .find("| 1 | Diverse (seed 0) |")
        .expect("Diverse ranked 1");
    let narrow = current
        .find("| 3 | Narrow (seed 0) |")
        .expect("Narrow ranked 3, after Diverse's two seeds");
    assert!(diverse < narrow);
    for axis in ["start_shift", "obs_noise", "latency", "dynamics", "Overall"] {
        // Markdown escapes the underscores.
        assert!(
            current.contains(&axis.replace('_', "\\_")),
            "{axis} column: {md}"
        );
    }
    assert!(
        md.contains("paired bootstrap"),
        "the note says what the intervals are"
    );

    let (ok, tex, err) = tables(&db, "latex");
    assert!(ok, "{err}");
    // Per suite version a methods table and a per-seed table.
    assert_eq!(tex.matches("\\begin{tabular}").count(), 4, "{tex}");
    assert!(tex.contains("per training seed"), "{tex}");
    assert!(tex.contains("Diverse (seed 0)") && tex.contains("\\toprule"));

    let (ok, csv, err) = tables(&db, "csv");
    assert!(ok, "{err}");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().unwrap().split(',').collect();
    assert_eq!(header[0], "task");
    let col = |name: &str| header.iter().position(|h| *h == name).unwrap();
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    // Per submission: level 0, the suite's levels, the axis scores, overall.
    let suite = d3il_evaluator::perturb::Suite::for_task(d3il_protocol::TaskId::Pushing).unwrap();
    let (n_levels, n_axes) = (suite.perturbations().len(), suite.file.axes.len());
    for id in &ids {
        let n = rows
            .iter()
            .filter(|r| r[col("submission_id")] == id.to_string())
            .count();
        assert_eq!(n, 1 + n_levels + n_axes + 1, "rows of submission {id}");
    }
    // Per method over seeds: level 0, each axis's score and the overall one.
    let diverse_all: Vec<&Vec<&str>> = rows
        .iter()
        .filter(|r| r[col("method")] == "Diverse" && r[col("training_seed")] == "all")
        .collect();
    assert_eq!(diverse_all.len(), 1 + n_axes + 1);
    let overall = diverse_all
        .iter()
        .find(|r| r[col("axis")] == "overall")
        .unwrap();
    assert_eq!(overall[col("n_seeds")], "2");
    assert!(overall[col("seeds_std")].parse::<f64>().unwrap() > 0.0);
    let narrow_dynamics_4: Vec<&Vec<&str>> = rows
        .iter()
        .filter(|r| {
            r[col("method")] == "Narrow" && r[col("axis")] == "dynamics" && r[col("level")] == "4"
        })
        .collect();
    assert_eq!(narrow_dynamics_4.len(), 1);
    let r = narrow_dynamics_4[0];
    let success: f64 = r[col("success_rate")].parse().unwrap();
    let drop: f64 = r[col("drop")].parse().unwrap();
    assert_eq!(success, 0.0, "14 − 4 × 4: no success left");
    assert!(drop > 0.8, "the paired drop from level 0: {drop}");
    let retained: f64 = r[col("retained")].parse().unwrap();
    assert_eq!(retained, 0.0);
}

#[test]
fn an_unknown_table_names_robustness_among_the_choices() {
    let out = Command::new(EXE)
        .args(["tables", "--table", "robust"])
        .output()
        .expect("run d3il tables");
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("robustness") && err.contains("main"), "{err}");
}

/// The same method from 3 initial states and from Pushing's 30: the 3-state
/// row carries its score intervals' label (`d3il bench intervals`: 66–74 %)
/// in the per-seed tables and on its CSV score lines; the 30-state row none.
#[test]
fn rows_from_few_initial_states_carry_their_score_intervals_label() {
    let dir = TempDir::new("robustness-tables-coverage");
    let db = dir.path().join("lb.sqlite");
    let full = document(&three()[0]);
    let few = first_states(full.clone(), 3);
    assert!(few.overall.and_then(|o| o.interval()).is_some());
    let ids = seed_documents(&db, &[("Three-States", 0, few), ("Thirty-States", 0, full)]);
    let label = "from 3 initial states: measured coverage 66–74 %, below the nominal 95 %";

    let (ok, md, err) = tables(&db, "markdown");
    assert!(ok, "{err}");
    assert!(
        md.contains("Score intervals' coverage |"),
        "the column: {md}"
    );
    let row = |name: &str| {
        md.lines()
            .find(|l| l.contains(&format!("| {name} (seed 0) |")))
            .unwrap_or_else(|| panic!("{name}'s row: {md}"))
            .to_string()
    };
    assert!(
        row("Three-States").ends_with(&format!("| {label} |")),
        "{md}"
    );
    assert!(row("Thirty-States").ends_with("|  |"), "{md}");
    assert_eq!(md.matches(label).count(), 1, "{md}");
    assert!(
        md.contains("fewer than 30 initial states are labelled"),
        "the note: {md}"
    );

    let (ok, tex, err) = tables(&db, "latex");
    assert!(ok, "{err}");
    let tex_row = tex
        .lines()
        .find(|l| l.contains("Three-States (seed 0)"))
        .expect("the 3-state row");
    assert!(tex_row.contains("below the nominal 95"), "{tex_row}");
    let tex_row = tex
        .lines()
        .find(|l| l.contains("Thirty-States (seed 0)"))
        .expect("the 30-state row");
    assert!(!tex_row.contains("measured coverage"), "{tex_row}");

    let (ok, csv, err) = tables(&db, "csv");
    assert!(ok, "{err}");
    assert!(csv.lines().next().unwrap().ends_with(",score_coverage"));
    // The label is the last column (quoted: it has a comma).
    for (id, want) in [(ids[0], format!(",\"{label}\"")), (ids[1], ",".into())] {
        let mine: Vec<&str> = csv
            .lines()
            .filter(|l| l.contains(&format!(",{id},")))
            .collect();
        let (scores, others): (Vec<&str>, Vec<&str>) =
            mine.iter().partition(|l| l.contains(",score,"));
        assert_eq!(scores.len(), 5, "four axes and overall: {csv}");
        assert!(scores.iter().all(|l| l.ends_with(&want)), "{csv}");
        assert!(
            others
                .iter()
                .all(|l| l.ends_with(',') && !l.contains(label)),
            "only score lines: {csv}"
        );
    }
}
