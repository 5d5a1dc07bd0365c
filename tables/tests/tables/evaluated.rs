//! Evaluated methods next to the paper's: where their rows go, how they are
//! labelled and which of their numbers are bold.

use d3il_protocol::{paper, ObsType, ResultCell, Source, Stat};
use d3il_tables::{build_table, render_table_with, Format, MethodInfo, SourceFilter, TableKind};
use std::collections::BTreeMap;

fn evaluated(method: &str, task: &str, success: f64, entropy: f64, n_seeds: usize) -> ResultCell {
    ResultCell {
        table: "main".to_string(),
        method: method.to_string(),
        task: task.to_string(),
        obs: ObsType::State,
        data_fraction: 1.0,
        control: None,
        source: Source::Evaluated,
        success_rate: Stat {
            mean: success,
            std: 0.0123,
        },
        entropy: Stat {
            mean: entropy,
            std: 0.0456,
        },
        n_seeds,
        bold_success: None,
        bold_entropy: None,
        initial_states: None,
        robot_look: None,
        build: None,
    }
}

/// Paper cells plus: a new history-free method that beats the paper's
/// history-free best success on Avoiding (0.760 bold, 0.851 best value), a
/// re-evaluation of BESO that does not beat the paper's BESO, and a new
/// history-based method (k = 10, given in the method map) with the best
/// history-based Avoiding success.
fn cells() -> Vec<ResultCell> {
    let mut c = paper::load_embedded().cells();
    c.push(evaluated("Diffusion-X", "Avoiding (T1)", 0.97, 0.5, 3));
    c.push(evaluated("Diffusion-X", "Aligning (T2)", 0.5, 0.9, 3));
    c.push(evaluated("BESO", "Avoiding (T1)", 0.9, 0.2, 3));
    c.push(evaluated("Zeta_GPT", "Avoiding (T1)", 0.96, 0.1, 3));
    c
}

fn methods() -> BTreeMap<String, MethodInfo> {
    BTreeMap::from([(
        "Zeta_GPT".to_string(),
        MethodInfo {
            history: 10,
            action_chunking: false,
        },
    )])
}

fn latex(source: SourceFilter) -> String {
    render_table_with(
        &cells(),
        TableKind::Main,
        ObsType::State,
        Format::Latex,
        source,
        &methods(),
    )
    .expect("render")
}

fn row_line<'a>(tex: &'a str, label: &str) -> &'a str {
    tex.lines()
        .find(|l| l.starts_with(&format!("{label} & ")))
        .unwrap_or_else(|| panic!("no row {label} in\n{tex}"))
}

fn cells_of(line: &str) -> Vec<&str> {
    line.trim_end_matches(" \\\\")
        .split(" & ")
        .skip(1)
        .collect()
}

#[test]
fn evaluated_rows_are_placed_after_the_paper_rows_and_labelled() {
    let tex = latex(SourceFilter::Both);
    let lines: Vec<&str> = tex.lines().collect();
    let pos = |label: &str| {
        lines
            .iter()
            .position(|l| l.starts_with(&format!("{label} & ")))
            .unwrap_or_else(|| panic!("no row {label}"))
    };
    // A paper method's evaluation follows its reported row.
    assert_eq!(
        pos("BESO$^{\\ddagger}$ (eval.)"),
        pos("BESO$^{\\ddagger}$") + 1
    );
    // New methods come after all paper rows, by name, after a rule; the
    // underscore is escaped and k = 10 earns the double dagger.
    let ddpm_act = pos("DDPM-ACT$^{\\dagger\\ddagger}$");
    let diffusion = pos("Diffusion-X (eval.)");
    let zeta = pos("Zeta\\_GPT$^{\\ddagger}$ (eval.)");
    assert_eq!(lines[ddpm_act + 1], "\\midrule");
    assert_eq!(diffusion, ddpm_act + 2);
    assert_eq!(zeta, diffusion + 1);
    // Diffusion-X has no Pushing value: `--` in that column.
    assert_eq!(cells_of(lines[diffusion])[4], "--");
    // Only the first block has evaluated rows.
    assert_eq!(tex.matches("(eval.)").count(), 3 + 1, "3 rows + caption");
    assert!(
        tex.contains("over 6 training seeds (reported rows) and 3 training seeds (evaluated rows)")
    );
    assert!(tex.contains("evaluated rows computed against all rows of their group"));
}

#[test]
fn evaluated_values_are_bold_when_best_of_their_history_group() {
    let tex = latex(SourceFilter::Both);
    // History-free: 0.970 beats VAE-ACT's 0.851; its entropy 0.5 does not beat IBC's 0.85.
    let d = cells_of(row_line(&tex, "Diffusion-X (eval.)"));
    assert_eq!(d[0], "$\\mathbf{0.970} {\\scriptstyle \\pm 0.012}$");
    assert_eq!(d[1], "$0.500 {\\scriptstyle \\pm 0.046}$");
    // Aligning entropy 0.9 beats DDPM-MLP's 0.712; success 0.5 does not.
    assert_eq!(d[2], "$0.500 {\\scriptstyle \\pm 0.012}$");
    assert_eq!(d[3], "$\\mathbf{0.900} {\\scriptstyle \\pm 0.046}$");
    // History-based: Zeta_GPT's 0.960 beats BESO's 0.950 (compared within its
    // group only: Diffusion-X's 0.970 is in the other group).
    let z = cells_of(row_line(&tex, "Zeta\\_GPT$^{\\ddagger}$ (eval.)"));
    assert_eq!(z[0], "$\\mathbf{0.960} {\\scriptstyle \\pm 0.012}$");
    assert_eq!(z[1], "$0.100 {\\scriptstyle \\pm 0.046}$");
    let b = cells_of(row_line(&tex, "BESO$^{\\ddagger}$ (eval.)"));
    assert_eq!(b[0], "$0.900 {\\scriptstyle \\pm 0.012}$");
    // Reported rows keep the paper's bold even where an evaluation beats them.
    let beso = cells_of(row_line(&tex, "BESO$^{\\ddagger}$"));
    assert_eq!(beso[0], "$\\mathbf{0.950} {\\scriptstyle \\pm 0.015}$");
}

#[test]
fn evaluated_only_tables_compare_evaluations_with_each_other() {
    let tex = latex(SourceFilter::Evaluated);
    assert!(
        !tex.contains("(eval.)"),
        "no annotation when all rows are evaluated"
    );
    assert!(!tex.contains("IBC"));
    assert!(tex.contains("All rows were evaluated by this leaderboard"));
    // BESO (history-based) now loses only to Zeta_GPT on success but has the
    // best history-based entropy (0.2 > 0.1).
    let b = cells_of(row_line(&tex, "BESO$^{\\ddagger}$"));
    assert_eq!(b[0], "$0.900 {\\scriptstyle \\pm 0.012}$");
    assert_eq!(b[1], "$\\mathbf{0.200} {\\scriptstyle \\pm 0.046}$");
    // The paper method's row comes first (paper order), new methods after a rule.
    let lines: Vec<&str> = tex.lines().collect();
    let beso = lines
        .iter()
        .position(|l| l.starts_with("BESO"))
        .expect("BESO row");
    assert_eq!(lines[beso + 1], "\\midrule");
    assert!(lines[beso + 2].starts_with("Diffusion-X & "));
    assert!(lines[beso + 3].starts_with("Zeta\\_GPT$^{\\ddagger}$ & "));
}

#[test]
fn unknown_methods_are_history_free_without_marks() {
    // Without the method map, Zeta_GPT competes with the history-free group,
    // where Diffusion-X's 0.970 beats its 0.960.
    let tex = render_table_with(
        &cells(),
        TableKind::Main,
        ObsType::State,
        Format::Latex,
        SourceFilter::Both,
        &BTreeMap::new(),
    )
    .expect("render");
    let z = cells_of(row_line(&tex, "Zeta\\_GPT (eval.)"));
    assert_eq!(z[0], "$0.960 {\\scriptstyle \\pm 0.012}$");
}

#[test]
fn markdown_and_csv_carry_the_same_numbers_and_bold() {
    let md = render_table_with(
        &cells(),
        TableKind::Main,
        ObsType::State,
        Format::Markdown,
        SourceFilter::Both,
        &methods(),
    )
    .expect("markdown");
    let row = md
        .lines()
        .find(|l| l.starts_with("| Diffusion-X (eval.) |"))
        .expect("markdown row");
    assert!(
        row.contains(
            "| **0.970** ± 0.012 | 0.500 ± 0.046 | 0.500 ± 0.012 | **0.900** ± 0.046 | – | – |"
        ),
        "{row}"
    );
    assert!(md.contains("| Zeta\\_GPT‡ (eval.) |"));

    let csv = render_table_with(
        &cells(),
        TableKind::Main,
        ObsType::State,
        Format::Csv,
        SourceFilter::Both,
        &methods(),
    )
    .expect("csv");
    assert!(csv.contains("main,state,Diffusion-X,evaluated,1,false,,Avoiding (T1),1,success_rate,0.970,0.012,3,true\n"));
    assert!(csv.contains(
        "main,state,Diffusion-X,evaluated,1,false,,Avoiding (T1),1,entropy,0.500,0.046,3,false\n"
    ));
    assert!(csv.contains(
        "main,state,Zeta_GPT,evaluated,10,false,,Avoiding (T1),1,success_rate,0.960,0.012,3,true\n"
    ));
    // 99 paper cells x 2 metrics + 4 evaluated cells x 2 metrics + header.
    assert_eq!(csv.lines().count(), 1 + 2 * 99 + 2 * 4);

    // The model behind all three formats agrees on every value.
    let model = build_table(
        &cells(),
        TableKind::Main,
        ObsType::State,
        SourceFilter::Both,
        &methods(),
    )
    .expect("model");
    let bold_evaluated: usize = model
        .blocks
        .iter()
        .flat_map(|b| &b.rows)
        .filter(|r| r.source == Source::Evaluated)
        .flat_map(|r| r.values.iter().flatten().flatten())
        .filter(|v| v.bold)
        .count();
    assert_eq!(bold_evaluated, 3);
    assert_eq!(
        md.matches("**").count() / 2 - 1,
        csv.matches(",true\n").count()
    );
}

#[test]
fn evaluated_inserting_and_datasize_points_reach_their_tables() {
    let mut c = paper::load_embedded().cells();
    c.push(evaluated("Diffusion-X", "Inserting (T6)", 0.7, 0.6, 2));
    let mut half = evaluated("Diffusion-X", "Aligning (T2)", 0.4, 0.3, 2);
    half.table = "datasize".to_string();
    half.data_fraction = 0.5;
    c.push(half);
    c.push(evaluated("Diffusion-X", "Aligning (T2)", 0.8, 0.35, 2));
    let prelim = render_table_with(
        &c,
        TableKind::Prelim,
        ObsType::State,
        Format::Csv,
        SourceFilter::Evaluated,
        &BTreeMap::new(),
    )
    .expect("prelim");
    assert_eq!(
        prelim,
        "table,obs,method,source,history,action_chunking,control,task,data_fraction,metric,mean,std,n_seeds,bold\n\
         prelim,state,Diffusion-X,evaluated,1,false,,Inserting (T6),1,success_rate,0.700,0.012,2,false\n\
         prelim,state,Diffusion-X,evaluated,1,false,,Inserting (T6),1,entropy,0.600,0.046,2,false\n"
    );
    // The evaluated run on all data is the 100 % point of the data-size curve.
    let datasize = render_table_with(
        &c,
        TableKind::Datasize,
        ObsType::State,
        Format::Csv,
        SourceFilter::Evaluated,
        &BTreeMap::new(),
    )
    .expect("datasize");
    let lines: Vec<&str> = datasize.lines().skip(1).collect();
    assert_eq!(lines.len(), 4);
    assert!(lines[0].contains(",Aligning (T2),0.5,success_rate,0.400,"));
    assert!(lines[2].contains(",Aligning (T2),1,success_rate,0.800,"));
}

#[test]
fn duplicate_and_corrupt_cells_are_refused_with_a_clear_message() {
    let mut c = cells();
    c.push(evaluated("Diffusion-X", "Avoiding (T1)", 0.1, 0.1, 3));
    let err = render_table_with(
        &c,
        TableKind::Main,
        ObsType::State,
        Format::Latex,
        SourceFilter::Both,
        &methods(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("Diffusion-X") && err.contains("rename"),
        "{err}"
    );

    let mut c = cells();
    c.push(evaluated("Broken", "Pushing (T3)", f64::NAN, 0.1, 3));
    let err = render_table_with(
        &c,
        TableKind::Main,
        ObsType::State,
        Format::Latex,
        SourceFilter::Both,
        &methods(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("Broken") && err.contains("re-evaluate"),
        "{err}"
    );
}

/// The same method evaluated on the original D3IL test contexts and on our
/// sample: two rows, each saying which initial states it used, never merged.
#[test]
fn rows_on_different_initial_state_sets_are_separate_and_labelled() {
    let on = |label: &str, success: f64| ResultCell {
        initial_states: Some(label.to_string()),
        ..evaluated("Setter", "Pushing (T3)", success, 0.5, 1)
    };
    let cells = vec![
        on("the original D3IL test contexts", 0.8),
        on("our sample", 0.6),
    ];
    let [original, sample] = evaluated_rows(
        &cells,
        ObsType::State,
        [
            "Setter (the original D3IL test contexts) & ",
            "Setter (our sample) & ",
        ],
    );
    assert!(original.contains("0.800"), "{original}");
    assert!(sample.contains("0.600"), "{sample}");
}

/// One method's image results drawn with the Panda meshes and with primitive
/// shapes: two rows, the second saying how its robot was drawn, never merged
/// (and no duplicate-cell error).
#[test]
fn image_rows_drawn_differently_are_separate_and_labelled() {
    let drawn = |look: Option<&str>, success: f64| ResultCell {
        obs: ObsType::Image,
        initial_states: Some("the original D3IL test contexts".into()),
        robot_look: look.map(str::to_string),
        ..evaluated("Looker", "Aligning (T2)", success, 0.5, 1)
    };
    let cells = vec![drawn(None, 0.8), drawn(Some("primitive robot"), 0.6)];
    let [meshed, primitive] = evaluated_rows(
        &cells,
        ObsType::Image,
        [
            "Looker (the original D3IL test contexts) & ",
            "Looker (the original D3IL test contexts, primitive robot) & ",
        ],
    );
    assert!(meshed.contains("0.800"), "{meshed}");
    assert!(primitive.contains("0.600"), "{primitive}");
}

/// One method evaluated by this build and by another (a different physics
/// fingerprint): two rows, the second saying why, never merged.
#[test]
fn rows_of_another_build_are_separate_and_labelled() {
    let by = |build: Option<&str>, success: f64| ResultCell {
        initial_states: Some("the original D3IL test contexts".into()),
        build: build.map(str::to_string),
        ..evaluated("Builder", "Pushing (T3)", success, 0.5, 1)
    };
    let other =
        "other build: physics fingerprint 0123456789abcdef, this build's is fedcba9876543210";
    let cells = vec![by(None, 0.8), by(Some(other), 0.6)];
    let theirs_prefix = format!("Builder (the original D3IL test contexts, {other}) & ");
    let [this, theirs] = evaluated_rows(
        &cells,
        ObsType::State,
        [
            "Builder (the original D3IL test contexts) & ",
            &theirs_prefix,
        ],
    );
    assert!(this.contains("0.800"), "{this}");
    assert!(theirs.contains("0.600"), "{theirs}");
}

/// The evaluated rows of `cells`' main LaTeX table whose lines start with
/// each of `prefixes` (a method name and its annotations, then ` & `).
fn evaluated_rows(cells: &[ResultCell], obs: ObsType, prefixes: [&str; 2]) -> [String; 2] {
    let tex = render_table_with(
        cells,
        TableKind::Main,
        obs,
        Format::Latex,
        SourceFilter::Evaluated,
        &methods(),
    )
    .unwrap();
    prefixes.map(|p| {
        tex.lines()
            .find(|l| l.starts_with(p))
            .unwrap_or_else(|| panic!("no row starting {p:?} in {tex}"))
            .to_string()
    })
}
