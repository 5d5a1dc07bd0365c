//! A result as text: the metrics table the CLI prints for an evaluation
//! (`d3il eval`, `d3il merge`, `d3il submit --wait`) and the behaviour counts
//! it shares with the server's behaviour plot and pages, so that both name
//! and order behaviours the same way.

use d3il_protocol::{Estimate, EvalResult, TaskId};
use std::collections::BTreeMap;

/// Successful-rollout counts per behaviour, named for the task
/// ([`d3il_protocol::behaviour_name`]), most frequent first, from
/// (success, behaviour) pairs.
pub fn behaviour_counts<'a>(
    task: TaskId,
    rollouts: impl IntoIterator<Item = (bool, &'a serde_json::Value)>,
) -> Vec<(String, usize)> {
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    for (_, b) in rollouts.into_iter().filter(|(success, _)| *success) {
        *counts
            .entry(crate::board::behaviour_label(task, b))
            .or_default() += 1;
    }
    let mut v: Vec<_> = counts.into_iter().collect();
    v.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    v
}

/// The metrics table `d3il eval` and `d3il merge` print, and `d3il submit
/// --wait` prints for the server's result: task, observation type, protocol, the metrics with
/// their intervals, the initial states, unstable rollouts and a histogram of
/// the behaviours of the successful rollouts.
pub fn metrics_table(result: &EvalResult) -> String {
    use std::fmt::Write as _;
    let mut out = String::new();
    let m = &result.metrics;
    let man = &result.manifest;
    let _ = writeln!(
        out,
        "task {}, {} observations ({} x {} rollouts, {} protocol, seed {})",
        man.task,
        man.obs_type,
        man.n_contexts,
        man.rollouts_per_context,
        man.protocol.as_str(),
        man.seed
    );
    if let Some(note) = man.robot_look_note() {
        let _ = writeln!(out, "note: {}", note.text);
    }
    let _ = writeln!(
        out,
        "{:<28} {:>8}   {:<32} interval",
        "metric", "value", "95% CI"
    );
    let mut reasons: Vec<(String, String)> = Vec::new();
    let mut line = |out: &mut String, name: &str, e: Estimate| {
        let method = match (e.no_interval, e.method) {
            (Some(why), _) => {
                reasons.push((name.to_string(), why.to_string()));
                String::new()
            }
            (None, Some(m)) => m.name().to_string(),
            (None, None) => e.interval_note(),
        };
        let _ = writeln!(
            out,
            "{name:<28} {:>8.3}   {:<32} {method}",
            e.value,
            e.interval_text(3)
        );
    };
    for (name, e) in [
        ("success rate", m.success_rate),
        ("conditional entropy", m.conditional_entropy),
        ("behaviour entropy", m.behaviour_entropy),
    ] {
        line(&mut out, name, e);
    }
    if let Some(levels) = &m.stacking_levels {
        for (i, l) in levels.iter().enumerate() {
            for (what, e) in [
                ("success", l.success_rate),
                ("cond. entropy", l.conditional_entropy),
                ("behaviour entropy", l.behaviour_entropy),
            ] {
                line(&mut out, &format!("stacking-{} {what}", i + 1), e);
            }
        }
    } else if let Some(s) = m.stacking {
        let _ = writeln!(
            out,
            "{:<28} {:.3} / {:.3} / {:.3}",
            "stacking-1/2/3 success", s[0], s[1], s[2]
        );
    }
    let _ = writeln!(
        out,
        "{:<28} {:>8.3}",
        "inference ms per call", m.inference_ms
    );
    for (name, why) in reasons {
        let _ = writeln!(out, "{name}: {why}");
    }
    let _ = writeln!(
        out,
        "initial states: {} ({}), sha256 {}",
        man.initial_states_name(),
        man.initial_states_origin(),
        man.initial_states_sha256
    );
    let _ = writeln!(
        out,
        "rollouts ended unstable: {} of {} (counted as failures)",
        result.rollouts_ended_unstable,
        result.rollouts.len()
    );
    if result.mostly_unstable() {
        let _ = writeln!(
            out,
            "WARNING: more than half of the rollouts ended with an unstable simulation; \
             these numbers say more about the simulation than about the policy"
        );
    }
    // The same counts and labels as the server's behaviour plot.
    let counts = behaviour_counts(
        result.manifest.task,
        result.rollouts.iter().map(|r| (r.success, &r.behaviour)),
    );
    let successes: usize = counts.iter().map(|c| c.1).sum();
    if counts.is_empty() {
        let _ = writeln!(out, "behaviours: no successful rollout");
    } else {
        let _ = writeln!(out, "behaviours of the {successes} successful rollouts:");
        let top = counts.iter().map(|c| c.1).max().unwrap_or(1).max(1);
        let width = counts
            .iter()
            .map(|c| c.0.chars().count())
            .max()
            .unwrap_or(0);
        for (label, n) in &counts {
            let bar = (n * 40).div_ceil(top);
            let _ = writeln!(out, "  {label:<width$} {n:>6}  {}", "#".repeat(bar));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::metrics_table;
    use d3il_protocol::{ObsType, ProtocolKind, RobotLook};
    use d3il_test_support::{pushing_result, SynthRollout};

    #[test]
    fn the_table_says_when_image_frames_were_not_drawn_as_the_original() {
        let mut r = pushing_result(ProtocolKind::Quick, |_, r| SynthRollout {
            success: r == 0,
            label: 0,
            unstable: false,
        });
        assert!(!metrics_table(&r).contains("note:"), "state: nothing drawn");
        r.manifest.obs_type = ObsType::Image;
        r.manifest.robot_look = Some(RobotLook::Meshes);
        assert!(
            !metrics_table(&r).contains("note:"),
            "drawn as the original"
        );
        r.manifest.robot_look = Some(RobotLook::Primitives);
        let table = metrics_table(&r);
        assert!(
            table.contains("\nnote: robot drawn with primitive shapes"),
            "{table}"
        );
    }
}
