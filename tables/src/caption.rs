//! The caption: what is shown, under which protocol, over how many seeds, and
//! what the marks and bold mean. Built once from the model's facts and written
//! in LaTeX or plain (Unicode) text.

use crate::model::{task_number, task_sort_key, Metric, TableModel};
use crate::numfmt::latex_escape;
use crate::TableKind;
use std::collections::BTreeSet;

#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Style {
    Latex,
    Plain,
}

impl Style {
    fn pm(self) -> &'static str {
        match self {
            Style::Latex => "$\\pm$",
            Style::Plain => "±",
        }
    }
    fn times(self) -> &'static str {
        match self {
            Style::Latex => "$\\times$",
            Style::Plain => "×",
        }
    }
    pub fn dagger(self) -> &'static str {
        match self {
            Style::Latex => "$\\dagger$",
            Style::Plain => "†",
        }
    }
    pub fn ddagger(self) -> &'static str {
        match self {
            Style::Latex => "$\\ddagger$",
            Style::Plain => "‡",
        }
    }
    fn text(self, s: &str) -> String {
        match self {
            Style::Latex => latex_escape(s),
            Style::Plain => s.to_string(),
        }
    }
}

fn seeds(set: &BTreeSet<usize>) -> String {
    match (set.first(), set.last()) {
        (Some(a), Some(b)) if a == b => {
            format!("{a} training seed{}", if *a == 1 { "" } else { "s" })
        }
        (Some(a), Some(b)) => format!("{a} to {b} training seeds"),
        _ => "no training seeds".to_string(),
    }
}

fn join_tasks(tasks: &[String]) -> String {
    match tasks.len() {
        0 => String::new(),
        1 => tasks[0].clone(),
        n => format!("{} and {}", tasks[..n - 1].join(", "), tasks[n - 1]),
    }
}

/// The paper's protocol for the task families shown (spec: paper JSON `protocol`).
fn protocol_list(m: &TableModel, style: Style) -> Vec<String> {
    let shown: BTreeSet<u32> = m
        .facts
        .tasks
        .iter()
        .filter_map(|t| task_number(t))
        .collect();
    let Some(obj) = m.facts.paper_protocol.as_object() else {
        return Vec::new();
    };
    let mut keys: Vec<&String> = obj.keys().collect();
    keys.sort_by_key(|k| task_sort_key(k));
    keys.into_iter()
        .filter(|k| task_number(k).is_some_and(|n| shown.contains(&n)))
        .filter_map(|k| {
            let e = &obj[k.as_str()];
            let states = e.get("initial_states").and_then(|v| v.as_u64());
            let rollouts = e.get("rollouts_per_state").and_then(|v| v.as_u64());
            let sims = e.get("simulations").and_then(|v| v.as_u64());
            let k = style.text(k);
            match (states, rollouts, sims) {
                (Some(s), Some(r), _) => Some(format!(
                    "{k} {s} initial states {} {r} rollouts",
                    style.times()
                )),
                (_, _, Some(n)) => Some(format!("{k} {n} rollouts")),
                _ => None,
            }
        })
        .collect()
}

pub fn caption(m: &TableModel, style: Style) -> String {
    let f = &m.facts;
    let obs = m.obs.as_str();
    let tasks = style.text(&join_tasks(&f.tasks));
    let mut s: Vec<String> = Vec::new();
    s.push(match m.kind {
        TableKind::Main => format!("Performance of {obs}-based policies on the D3IL tasks."),
        TableKind::Datasize => format!(
            "Performance of {obs}-based policies on {tasks} trained on a fraction of the demonstrations."
        ),
        TableKind::Posvel => {
            format!("Velocity versus position control of {obs}-based policies on {tasks}.")
        }
        TableKind::Prelim => format!("Preliminary results of {obs}-based policies on {tasks}."),
    });
    let seeds_text = match (f.reported_seeds.is_empty(), f.evaluated_seeds.is_empty()) {
        (false, false) => format!(
            "{} (reported rows) and {} (evaluated rows)",
            seeds(&f.reported_seeds),
            seeds(&f.evaluated_seeds)
        ),
        (false, true) => seeds(&f.reported_seeds),
        _ => seeds(&f.evaluated_seeds),
    };
    s.push(format!(
        "Success rate and conditional behaviour entropy (higher is better for both), mean {} standard deviation over {seeds_text}.",
        style.pm()
    ));
    let has_subtasks = m.blocks.iter().any(|b| {
        b.groups
            .iter()
            .any(|g| g.metrics.iter().any(|x| matches!(x, Metric::Subtask(_))))
    });
    if has_subtasks {
        s.push("Arranging also lists the success rates of its sub-tasks.".to_string());
    }
    if !f.reported_seeds.is_empty() {
        let list = protocol_list(m, style);
        if list.is_empty() {
            s.push(
                "Reported rows are the numbers published by Jia et al. (ICLR 2024).".to_string(),
            );
        } else {
            s.push(format!(
                "Reported rows are the numbers published by Jia et al. (ICLR 2024), measured with the paper's protocol: {}.",
                list.join("; ")
            ));
        }
    }
    if !f.evaluated_seeds.is_empty() {
        let who = if m.annotate_source() {
            "Rows marked (eval.) were"
        } else {
            "All rows were"
        };
        s.push(format!(
            "{who} evaluated by this leaderboard in its MuJoCo re-implementation of D3IL with the paper's protocol (the same fixed initial states and rollouts per state)."
        ));
    }
    match (f.any_dagger, f.any_ddagger) {
        (true, true) => s.push(format!(
            "{} action chunking; {} history.",
            style.dagger(),
            style.ddagger()
        )),
        (true, false) => s.push(format!("{} action chunking.", style.dagger())),
        (false, true) => s.push(format!("{} history.", style.ddagger())),
        (false, false) => {}
    }
    if m.kind == TableKind::Main {
        let how = match (f.reported_seeds.is_empty(), f.evaluated_seeds.is_empty()) {
            (false, false) => " (reported rows as printed in the paper; evaluated rows computed against all rows of their group)",
            (false, true) => " (as printed in the paper)",
            _ => "",
        };
        s.push(format!(
            "Bold: the best value of the history-free and of the history-based group{how}."
        ));
    }
    s.join(" ")
}
