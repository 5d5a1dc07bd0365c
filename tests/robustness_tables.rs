//! `d3il tables --table robustness` from a database holding robustness
//! results (written as a worker stores them): one table per suite version,
//! ranked by overall score, methods aggregated over training seeds (mean ±
//! std, as the boards) with the rows per seed after them, in Markdown, LaTeX
//! and CSV; a database without any says what to do.

mod robustness_support;
mod server_support;
use robustness_support::{seed, three_and_a_second_seed, OTHER_SHA256};
use server_support::*;
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
