//! What the leaderboards show, as pure functions (no HTTP, no SQL): board rows
//! and their views, seed grouping and aggregation (with the metrics crate's
//! one [`aggregate_seeds`]), ranking, sorting and behaviour counts (what the
//! figures are drawn from is in `board_figures`). The store feeds it typed
//! records; the API, the pages and the plots all read the rows it builds.

use crate::schema;
use d3il_metrics::{aggregate_seeds, MetricsError};
use d3il_protocol::{
    robot_look_note, ObsType, ProtocolKind, ResultCell, RobotLook, RobotLookNote, Source,
    StackingLevel, Stat, TaskId,
};
use std::collections::{BTreeMap, BTreeSet, HashMap};

/// One leaderboard row: a method on a task (paper title), observation type and
/// data fraction, aggregated over training seeds.
#[derive(Debug, Clone, PartialEq, serde::Serialize, utoipa::ToSchema)]
pub struct BoardRow {
    pub method: String,
    pub method_id: i64,
    /// The paper's table the row is from (`main`, `datasize`, ...).
    pub paper_table: String,
    /// The task as the paper titles it (`Stacking-2 (T5)`).
    pub task_title: String,
    #[schema(value_type = Option<schema::Task>)]
    pub task: Option<TaskId>,
    #[schema(value_type = schema::Obs)]
    pub obs: ObsType,
    pub data_fraction: f64,
    /// The control ablation (`pos`/`vel`) of reported ablation rows.
    pub control: Option<String>,
    #[schema(value_type = schema::Source)]
    pub source: Source,
    /// Evaluation protocol of evaluated rows (None for reported rows).
    #[schema(value_type = Option<schema::Protocol>)]
    pub protocol: Option<ProtocolKind>,
    #[schema(value_type = schema::Stat)]
    pub success: Stat,
    /// Conditional behaviour entropy (the paper's "Entropy").
    #[schema(value_type = schema::Stat)]
    pub entropy: Stat,
    /// Marginal behaviour entropy H(pi(beta)) (evaluated rows only).
    #[schema(value_type = Option<schema::Stat>)]
    pub behaviour_entropy: Option<Stat>,
    pub n_seeds: usize,
    pub inference_ms: Option<f64>,
    pub bold_success: Option<bool>,
    pub bold_entropy: Option<bool>,
    pub submission_ids: Vec<i64>,
    /// Evaluated rows: the initial-state set (e.g. `pushing-v2.json`); rows
    /// on different sets are never merged.
    pub initial_states: Option<String>,
    /// Evaluated rows: "the original D3IL test contexts" or "our sample".
    pub initial_states_label: Option<String>,
    /// Evaluated image rows: how the robot was drawn (null for state rows,
    /// reported rows and image results stored before it was recorded); rows
    /// drawn differently are never merged.
    #[schema(value_type = Option<schema::RobotLook>)]
    pub robot_look: Option<RobotLook>,
    /// Evaluated rows: the physics fingerprint of the build that made them
    /// (null before builds were identified); rows of different fingerprints
    /// are never merged or ranked together.
    pub physics_fingerprint: Option<String>,
    /// Evaluated rows of the zoo: where the training data came
    /// from ("trained here on d3il demos v1"); null for submitted rows.
    /// Rows of different data sources are never merged or ranked together.
    pub data_source: Option<String>,
    /// An operator marked the method as a baseline: the boards
    /// say so on its rows.
    pub baseline: bool,
}

/// Why an evaluated row made with `fingerprint` is not this build's (None:
/// it is, or neither is known). `current` is the physics fingerprint of the
/// build showing the row, once known (a server's drift canary,
/// `crate::canary::Canary::fingerprint`; None for `d3il tables`).
pub fn other_build_note(fingerprint: Option<&str>, current: Option<&str>) -> Option<String> {
    match (fingerprint, current) {
        (Some(f), Some(cur)) if f == cur => None,
        (Some(f), Some(cur)) => Some(format!(
            "other build: physics fingerprint {f}, this build's is {cur}"
        )),
        (Some(f), None) => Some(format!("physics fingerprint {f}")),
        (None, Some(_)) => Some("other build: made before builds were identified".into()),
        (None, None) => None,
    }
}

impl BoardRow {
    /// How an evaluated row's robot was drawn, when not as the original
    /// draws it (reported rows: None).
    pub fn robot_look_note(&self) -> Option<RobotLookNote> {
        match self.source {
            Source::Reported => None,
            Source::Evaluated => robot_look_note(self.obs, self.robot_look),
        }
    }

    /// Evaluated rows of another build than the one with the `current`
    /// physics fingerprint: why.
    pub fn build_note(&self, current: Option<&str>) -> Option<String> {
        match self.source {
            Source::Reported => None,
            Source::Evaluated => other_build_note(self.physics_fingerprint.as_deref(), current),
        }
    }

    /// The row as a table cell, shown by the build with the `current`
    /// physics fingerprint.
    pub fn to_cell(&self, current: Option<&str>) -> ResultCell {
        ResultCell {
            table: self.paper_table.clone(),
            method: self.method.clone(),
            task: self.task_title.clone(),
            obs: self.obs,
            data_fraction: self.data_fraction,
            control: self.control.clone(),
            source: self.source,
            success_rate: self.success,
            entropy: self.entropy,
            n_seeds: self.n_seeds,
            bold_success: self.bold_success,
            bold_entropy: self.bold_entropy,
            initial_states: self.initial_states_label.clone(),
            robot_look: self.robot_look_note().map(|n| n.badge.to_string()),
            // Rows of another build are kept apart in the tables too, with
            // the reason in the row's annotation.
            build: self.build_note(current),
        }
    }
}

/// Maps a task title as the paper prints it (`Stacking-2 (T5)`) to our task.
pub fn task_for_title(title: &str) -> Option<TaskId> {
    if let Some(t) = TaskId::ALL.into_iter().find(|t| t.title() == title) {
        return Some(t);
    }
    if title.starts_with("Stacking-") {
        return Some(TaskId::Stacking);
    }
    None
}

/// The anchor of a task title's section on its task board (`Stacking-2 (T5)`
/// → `stacking-2-t5`): the main table's cells link to `/tasks/<slug>#<anchor>`.
pub fn section_anchor(title: &str) -> String {
    title
        .to_ascii_lowercase()
        .split(|c: char| !c.is_ascii_alphanumeric())
        .filter(|w| !w.is_empty())
        .collect::<Vec<_>>()
        .join("-")
}

/// The link to a task title's section on its task board.
pub fn section_url(task: TaskId, title: &str, obs: impl std::fmt::Display) -> String {
    format!("/tasks/{}?obs={obs}#{}", task.slug(), section_anchor(title))
}

/// `paper` or `quick`, as stored and as the CSV prints it.
pub fn protocol_str(p: ProtocolKind) -> &'static str {
    p.as_str()
}

// ------------------------------------------------------------ seed grouping

/// The result of one completed submission (one training seed), as stored.
#[derive(Debug, Clone)]
pub struct EvaluatedSeed {
    pub submission_id: i64,
    pub method: String,
    pub method_id: i64,
    pub task: TaskId,
    pub obs: ObsType,
    pub training_seed: i64,
    pub data_fraction: f64,
    pub protocol: ProtocolKind,
    pub success_rate: f64,
    pub behaviour_entropy: f64,
    pub conditional_entropy: f64,
    /// Stacking-1/2/3 success rates of results stored before the levels had
    /// their own entropies.
    pub stacking: Option<[f64; 3]>,
    pub stacking_levels: Option<[StackingLevel; 3]>,
    pub inference_ms: f64,
    /// The initial-state set the result used (e.g. `pushing-v2.json`).
    pub initial_states: String,
    /// Image results: how the robot was drawn (None before it was recorded).
    pub robot_look: Option<RobotLook>,
    /// The build's physics fingerprint (None before builds were identified).
    pub physics_fingerprint: Option<String>,
    /// The zoo's data source (None: a submitted policy).
    pub data_source: Option<String>,
}

impl EvaluatedSeed {
    /// (task title, success, conditional entropy, behaviour entropy) of each
    /// row this seed contributes to: Stacking is reported as the paper's
    /// Stacking-1/2/3 rows, each with its own success rate and entropies.
    fn variants(&self) -> Vec<(String, f64, f64, f64)> {
        let stacking_title = |k: usize| format!("Stacking-{} (T5)", k + 1);
        match (self.task, &self.stacking_levels, &self.stacking) {
            (TaskId::Stacking, Some(l), _) => (0..3)
                .map(|k| {
                    (
                        stacking_title(k),
                        l[k].success_rate.value,
                        l[k].conditional_entropy.value,
                        l[k].behaviour_entropy.value,
                    )
                })
                .collect(),
            // Stored before the levels had their own entropies: the three
            // rates with the one (Stacking-3) entropy the result carries.
            (TaskId::Stacking, None, Some(s)) => (0..3)
                .map(|k| {
                    (
                        stacking_title(k),
                        s[k],
                        self.conditional_entropy,
                        self.behaviour_entropy,
                    )
                })
                .collect(),
            _ => vec![(
                self.task.title().to_string(),
                self.success_rate,
                self.conditional_entropy,
                self.behaviour_entropy,
            )],
        }
    }
}

/// Groups seeds into rows (method, task title, obs, fraction, protocol) in
/// order of first appearance, aggregating each metric over the seeds with
/// [`aggregate_seeds`] (mean and sample std; one seed has std 0).
pub fn evaluated_rows(seeds: &[EvaluatedSeed]) -> Result<Vec<BoardRow>, MetricsError> {
    type Key = (
        i64,
        String,
        &'static str,
        u64,
        &'static str,
        String,
        Option<RobotLook>,
        Option<String>,
        Option<String>,
    );
    struct Group<'a> {
        first: &'a EvaluatedSeed,
        title: String,
        success: Vec<f64>,
        entropy: Vec<f64>,
        behaviour: Vec<f64>,
        inference: Vec<f64>,
        seeds: BTreeSet<i64>,
        submissions: Vec<i64>,
    }
    let mut index: HashMap<Key, usize> = HashMap::new();
    let mut groups: Vec<Group> = vec![];
    for s in seeds {
        for (title, success, conditional, behaviour) in s.variants() {
            let key: Key = (
                s.method_id,
                title.clone(),
                s.obs.as_str(),
                s.data_fraction.to_bits(),
                protocol_str(s.protocol),
                s.initial_states.clone(),
                s.robot_look,
                s.physics_fingerprint.clone(),
                s.data_source.clone(),
            );
            let i = *index.entry(key).or_insert_with(|| {
                groups.push(Group {
                    first: s,
                    title,
                    success: vec![],
                    entropy: vec![],
                    behaviour: vec![],
                    inference: vec![],
                    seeds: BTreeSet::new(),
                    submissions: vec![],
                });
                groups.len() - 1
            });
            let g = &mut groups[i];
            g.success.push(success);
            g.entropy.push(conditional);
            g.behaviour.push(behaviour);
            g.inference.push(s.inference_ms);
            g.seeds.insert(s.training_seed);
            g.submissions.push(s.submission_id);
        }
    }
    groups
        .into_iter()
        .map(|g| {
            let f = g.first;
            Ok(BoardRow {
                baseline: false,
                method: f.method.clone(),
                method_id: f.method_id,
                paper_table: if f.data_fraction == 1.0 {
                    "main"
                } else {
                    "datasize"
                }
                .into(),
                task_title: g.title,
                task: Some(f.task),
                obs: f.obs,
                data_fraction: f.data_fraction,
                control: None,
                source: Source::Evaluated,
                protocol: Some(f.protocol),
                success: aggregate_seeds(&g.success)?,
                entropy: aggregate_seeds(&g.entropy)?,
                behaviour_entropy: Some(aggregate_seeds(&g.behaviour)?),
                n_seeds: g.seeds.len(),
                inference_ms: Some(aggregate_seeds(&g.inference)?.mean),
                bold_success: None,
                bold_entropy: None,
                submission_ids: g.submissions,
                initial_states: Some(f.initial_states.clone()),
                initial_states_label: Some(
                    d3il_protocol::InitialStatesOrigin::of(&f.initial_states)
                        .label()
                        .to_string(),
                ),
                robot_look: f.robot_look,
                physics_fingerprint: f.physics_fingerprint.clone(),
                data_source: f.data_source.clone(),
            })
        })
        .collect()
}

// ------------------------------------------------------------------- views

/// Which rows of a task a leaderboard shows (`?view=`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum View {
    /// Full training data, no control ablation, no data-size table.
    Main,
    /// The paper's data-size rows and evaluated rows at every fraction.
    DataFraction,
}

impl View {
    /// `None` and `""` are the main view; anything else unknown is an error
    /// message naming the choices.
    pub fn parse(s: Option<&str>) -> Result<View, String> {
        match s {
            None | Some("") | Some("main") => Ok(View::Main),
            Some("data-fraction") => Ok(View::DataFraction),
            Some(other) => Err(format!(
                "unknown view `{other}`; use `main` or `data-fraction`"
            )),
        }
    }

    pub fn as_str(self) -> &'static str {
        match self {
            View::Main => "main",
            View::DataFraction => "data-fraction",
        }
    }

    pub fn rows(self, rows: &[BoardRow], task: TaskId, obs: ObsType) -> Vec<BoardRow> {
        match self {
            View::Main => board_for(rows, task, obs),
            View::DataFraction => fraction_rows(rows, task, obs),
        }
    }
}

/// Rows of the leaderboard of `task` and `obs`: full training data, no
/// control ablation, no data-size table (that is the data-fraction view).
pub fn board_for(rows: &[BoardRow], task: TaskId, obs: ObsType) -> Vec<BoardRow> {
    rows.iter()
        .filter(|r| {
            r.task == Some(task)
                && r.obs == obs
                && r.data_fraction == 1.0
                && r.control.is_none()
                && r.paper_table != "datasize"
        })
        .cloned()
        .collect()
}

/// Rows of the data-fraction view: the paper's data-size table and evaluated
/// rows at any fraction (full-data evaluated rows included as the 1.0 point).
pub fn fraction_rows(rows: &[BoardRow], task: TaskId, obs: ObsType) -> Vec<BoardRow> {
    rows.iter()
        .filter(|r| {
            r.task == Some(task)
                && r.obs == obs
                && r.control.is_none()
                && (r.paper_table == "datasize" || r.source == Source::Evaluated)
        })
        .cloned()
        .collect()
}

/// Splits rows by paper task title, keeping first-seen order (Stacking has
/// three: Stacking-1/2/3).
pub fn by_title(rows: Vec<BoardRow>) -> Vec<(String, Vec<BoardRow>)> {
    let mut out: Vec<(String, Vec<BoardRow>)> = vec![];
    for r in rows {
        match out.iter_mut().find(|(t, _)| *t == r.task_title) {
            Some((_, v)) => v.push(r),
            None => out.push((r.task_title.clone(), vec![r])),
        }
    }
    out
}

// ----------------------------------------------------------------- ranking

/// Rows ranked together on a board. Rows of different groups are never
/// interleaved: numbers evaluated here, numbers the paper reports, numbers on
/// different initial-state sets and quick smoke tests are not comparable.
#[derive(Debug, Clone, PartialEq, Eq, PartialOrd, Ord)]
pub enum RankGroup {
    /// Evaluated here with the full (paper) protocol on one initial-state set
    /// and, for image rows, with the robot drawn one way (None: as the
    /// original draws it).
    Evaluated(String, Option<RobotLookNote>, Option<String>),
    /// The zoo: evaluated like the above, trained here on the
    /// data source named first; never ranked with submitted or paper rows.
    Zoo(String, String, Option<RobotLookNote>, Option<String>),
    /// Reported in the D3IL paper.
    Reported,
    /// Quick-protocol smoke tests: below the board, unranked, off the Pareto front.
    Smoke,
}

impl RankGroup {
    pub fn of(r: &BoardRow) -> RankGroup {
        match (r.source, r.protocol) {
            (Source::Reported, _) => RankGroup::Reported,
            (Source::Evaluated, Some(ProtocolKind::Quick)) => RankGroup::Smoke,
            (Source::Evaluated, _) if r.data_source.is_some() => RankGroup::Zoo(
                r.data_source.clone().unwrap_or_default(),
                r.initial_states.clone().unwrap_or_default(),
                r.robot_look_note(),
                r.physics_fingerprint.clone(),
            ),
            (Source::Evaluated, _) => RankGroup::Evaluated(
                r.initial_states.clone().unwrap_or_default(),
                r.robot_look_note(),
                r.physics_fingerprint.clone(),
            ),
        }
    }

    /// Whether rows of the group get rank numbers (smoke tests do not).
    pub fn ranked(&self) -> bool {
        *self != RankGroup::Smoke
    }

    /// The group's heading on the board of the build with the `current`
    /// physics fingerprint.
    pub fn heading(&self, current: Option<&str>) -> String {
        match self {
            RankGroup::Evaluated(set, look, fingerprint) => {
                let mut notes = vec![format!("initial states {set}")];
                notes.extend(look.as_ref().map(|l| l.badge.to_string()));
                notes.extend(other_build_note(fingerprint.as_deref(), current));
                format!("Evaluated here ({})", notes.join("; "))
            }
            RankGroup::Zoo(source, set, look, fingerprint) => {
                let mut notes = vec![format!("initial states {set}")];
                notes.extend(look.as_ref().map(|l| l.badge.to_string()));
                notes.extend(other_build_note(fingerprint.as_deref(), current));
                let mut c = source.chars();
                let s: String = c
                    .next()
                    .into_iter()
                    .flat_map(char::to_uppercase)
                    .chain(c)
                    .collect();
                format!("{s}: the zoo ({})", notes.join("; "))
            }
            RankGroup::Reported => "Reported in the D3IL paper".into(),
            RankGroup::Smoke => "Smoke tests (quick protocol, not ranked)".into(),
        }
    }
}

/// Splits rows into their [`RankGroup`]s: evaluated (one group per
/// initial-state set and robot look), then reported, then smoke tests; row order is kept
/// within a group.
pub fn rank_groups(rows: Vec<BoardRow>) -> Vec<(RankGroup, Vec<BoardRow>)> {
    let mut groups: BTreeMap<RankGroup, Vec<BoardRow>> = BTreeMap::new();
    for r in rows {
        groups.entry(RankGroup::of(&r)).or_default().push(r);
    }
    groups.into_iter().collect()
}

// ----------------------------------------------------------------- sorting

/// Sortable columns: (query key, column header).
pub const SORT_KEYS: [(&str, &str); 7] = [
    ("method", "Method"),
    ("source", "Source"),
    ("success", "Success rate"),
    ("entropy", "Cond. entropy"),
    ("behaviour", "Behaviour entropy"),
    ("seeds", "Seeds"),
    ("inference", "Inference (ms)"),
];

/// Sorts by one of [`SORT_KEYS`]; missing values sort last in either direction.
pub fn sort_rows(rows: &mut [BoardRow], key: &str, desc: bool) {
    let val = |r: &BoardRow| -> f64 {
        let v = match key {
            "entropy" => r.entropy.mean,
            "behaviour" => r.behaviour_entropy.map(|s| s.mean).unwrap_or(f64::NAN),
            "seeds" => r.n_seeds as f64,
            "inference" => r.inference_ms.unwrap_or(f64::NAN),
            _ => r.success.mean,
        };
        if v.is_finite() {
            v
        } else if desc {
            f64::NEG_INFINITY
        } else {
            f64::INFINITY
        }
    };
    match key {
        "method" => rows.sort_by_key(|a| a.method.to_lowercase()),
        "source" => rows.sort_by_key(|r| r.source),
        _ => rows.sort_by(|a, b| val(a).total_cmp(&val(b))),
    }
    if desc {
        rows.reverse();
    }
}

/// Successful-rollout counts per behaviour (the same as `d3il eval`'s table).
pub use d3il_tables::summary::behaviour_counts;

#[cfg(test)]
mod tests {
    use super::*;

    fn seed(id: i64, training_seed: i64, success: f64) -> EvaluatedSeed {
        EvaluatedSeed {
            submission_id: id,
            method: "M".into(),
            method_id: 7,
            task: TaskId::Aligning,
            obs: ObsType::State,
            training_seed,
            data_fraction: 1.0,
            protocol: ProtocolKind::Paper,
            success_rate: success,
            behaviour_entropy: 0.5,
            conditional_entropy: 0.25,
            stacking: None,
            stacking_levels: None,
            inference_ms: 2.0,
            initial_states: "pushing-v2.json".into(),
            robot_look: None,
            physics_fingerprint: None,
            data_source: None,
        }
    }

    #[test]
    fn seeds_aggregate_with_sample_std() {
        let rows = evaluated_rows(&[
            seed(1, 0, 1.0),
            seed(2, 1, 2.0),
            seed(3, 2, 3.0),
            seed(4, 3, 4.0),
        ])
        .unwrap();
        assert_eq!(rows.len(), 1);
        let r = &rows[0];
        assert!((r.success.mean - 2.5).abs() < 1e-12);
        // var = (2.25 + 0.25 + 0.25 + 2.25) / 3 = 5/3
        assert!((r.success.std - (5.0f64 / 3.0).sqrt()).abs() < 1e-12);
        assert_eq!(r.n_seeds, 4);
        assert_eq!(r.submission_ids, vec![1, 2, 3, 4]);
        // One seed: std 0 (as the paper's tables over one seed).
        let one = evaluated_rows(&[seed(9, 0, 0.7)]).unwrap();
        assert_eq!((one[0].success.mean, one[0].success.std), (0.7, 0.0));
    }

    #[test]
    fn quick_reported_and_other_sets_are_ranked_apart() {
        let mut quick = seed(5, 0, 1.0);
        quick.protocol = ProtocolKind::Quick;
        let mut other_set = seed(6, 1, 0.9);
        other_set.initial_states = "pushing-v1.json".into();
        let mut rows = evaluated_rows(&[seed(1, 0, 0.5), quick, other_set]).unwrap();
        let mut reported = rows[0].clone();
        reported.source = Source::Reported;
        reported.protocol = None;
        reported.initial_states = None;
        rows.push(reported);
        let groups: Vec<RankGroup> = rank_groups(rows.clone()).into_iter().map(|g| g.0).collect();
        assert_eq!(
            groups,
            vec![
                RankGroup::Evaluated("pushing-v1.json".into(), None, None),
                RankGroup::Evaluated("pushing-v2.json".into(), None, None),
                RankGroup::Reported,
                RankGroup::Smoke
            ]
        );
        // The quick run (success 1.0) is off the Pareto front.
        let points = crate::board_figures::pareto_points(&rows);
        assert_eq!(points.len(), 3);
        assert!(points.iter().all(|p| p.success.mean < 1.0));
    }

    #[test]
    fn image_rows_drawn_differently_are_neither_merged_nor_ranked_together() {
        let image = |id, training_seed, look| EvaluatedSeed {
            obs: ObsType::Image,
            robot_look: look,
            physics_fingerprint: None,
            ..seed(id, training_seed, 0.5)
        };
        let rows = evaluated_rows(&[
            image(1, 0, Some(RobotLook::Meshes)),
            image(2, 1, Some(RobotLook::Primitives)),
            image(3, 1, Some(RobotLook::Meshes)),
            image(4, 2, None),
        ])
        .unwrap();
        let looks: Vec<(Option<RobotLook>, usize)> =
            rows.iter().map(|r| (r.robot_look, r.n_seeds)).collect();
        assert_eq!(
            looks,
            vec![
                (Some(RobotLook::Meshes), 2),
                (Some(RobotLook::Primitives), 1),
                (None, 1)
            ]
        );
        let groups = rank_groups(rows);
        assert_eq!(groups.len(), 3, "{groups:?}");
        // Drawn as the original: the plain heading, first.
        assert_eq!(
            groups[0].0.heading(None),
            "Evaluated here (initial states pushing-v2.json)"
        );
        assert_eq!(groups[0].1[0].robot_look, Some(RobotLook::Meshes));
        let headings: Vec<String> = groups[1..].iter().map(|g| g.0.heading(None)).collect();
        assert!(
            headings.iter().any(|h| h.contains("primitive robot")),
            "{headings:?}"
        );
        assert!(
            headings.iter().any(|h| h.contains("not recorded")),
            "{headings:?}"
        );
        // State rows draw nothing: no note whatever the manifest says.
        let state = evaluated_rows(&[seed(5, 0, 0.5)]).unwrap();
        assert_eq!(state[0].robot_look_note(), None);
    }

    #[test]
    fn view_names() {
        assert_eq!(View::parse(None), Ok(View::Main));
        assert_eq!(View::parse(Some("data-fraction")), Ok(View::DataFraction));
        assert!(View::parse(Some("ablation"))
            .unwrap_err()
            .contains("data-fraction"));
    }

    /// The build showing a row is passed in (a server's canary), not kept in
    /// a process-wide global: every combination, in one process.
    #[test]
    fn rows_of_other_builds_say_so_against_the_build_showing_them() {
        assert_eq!(other_build_note(Some("a"), Some("a")), None);
        assert_eq!(
            other_build_note(Some("a"), Some("b")).as_deref(),
            Some("other build: physics fingerprint a, this build's is b")
        );
        assert_eq!(
            other_build_note(Some("a"), None).as_deref(),
            Some("physics fingerprint a")
        );
        assert_eq!(
            other_build_note(None, Some("b")).as_deref(),
            Some("other build: made before builds were identified")
        );
        assert_eq!(other_build_note(None, None), None);
    }
}
