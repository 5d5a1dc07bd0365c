//! Pictures of what rollouts did, drawn from their recorded traces
//! ([`RolloutTrace`]): one rollout seen from above, every rollout's TCP path
//! of a submission overlaid, where in the initial-state space a policy fails,
//! and the per-step signals of one rollout.
//!
//! Every top-down picture has the same orientation: seen from above with the
//! robot at the bottom. World x (away from the robot base) points up the page
//! and world y points to the left (the frame is right-handed with z up, so
//! this is the view from above, not a mirror image).
//!
//! The style is the one of [`crate::plot`]: plotters draws the axes, the data
//! marks are written in `<g class="...">` groups that tests read back. Each
//! top-down view carries its pixel mapping in a `<g class="top-down-frame">`
//! (`data-world-x="xmin xmax"` bottom to top, `data-world-y="ymin ymax"` right
//! to left, `data-px="left top right bottom"`); each step panel carries
//! `data-x-range`, `data-y-range` and `data-px` (x to the right, y up).
//! The groups: `tcp-path`, `object-path` (`data-object`), `start-mark` and
//! `end-mark` (`data-path`), `landmark table|target|obstacle` (`data-label`,
//! or `data-object` for a `target*` object), `rollout-path` (`failed` too for
//! a failed rollout; `data-behaviour`, `data-context`, `data-rollout`),
//! `points` (`data-panel` `success|behaviour`, markers with `data-context`
//! and `data-object`), `step-panel` (`data-panel` `action-k|speed|distance`,
//! lines with `data-series`), `colour-bar`, `caption`, `no-data`.
//!
//! Long paths are thinned to at most 400 points (evenly in time for one
//! rollout, by shape for the overlay); coordinates are written in pixels with
//! at most two decimals.

mod draw;
mod scene;
/// The pieces the other path plots share (`crate::figures`' Avoiding paths).
pub(crate) use draw::{caption_lines, draw_caption, Frame, Layer, CAPTION_ROW};
pub(crate) use scene::outside_note_of;
mod start_map;
mod steps;
mod top_down;

use crate::TablesError;
use d3il_protocol::rollout::{Landmark, UnpackedTrace};
use d3il_protocol::{EvalResult, RolloutRecord, RolloutTrace, TaskId};
use std::collections::BTreeMap;

pub use start_map::start_map_svg;
pub use steps::step_plots_svg;
pub use top_down::{overlay_svg, top_down_svg};

/// One initial state of an evaluation, for [`start_map_svg`].
#[derive(Debug, Clone, PartialEq)]
pub struct StartState {
    pub context_index: usize,
    /// Each object's position after the reset (`target*` objects are fixed
    /// targets and are not drawn).
    pub objects: Vec<(String, [f64; 3])>,
    /// Successful rollouts of this initial state over all of its rollouts.
    pub success_rate: f64,
    /// The most frequent behaviour label among its successful rollouts
    /// ([`d3il_protocol::behaviour_name`]); `None` when none succeeded.
    pub dominant_behaviour: Option<String>,
}

/// The initial states of an evaluation as [`start_map_svg`] draws them: per
/// initial state the start poses of the trace of its rollout 0
/// ([`EvalResult::trace_of`]), its success rate over its rollouts and the most
/// frequent behaviour label among its successful ones (ties go to the first
/// label in alphabetical order). Initial states without a trace are left out.
pub fn start_states(task: TaskId, result: &EvalResult) -> Vec<StartState> {
    // (rollouts, successes, behaviour counts, start objects) per context.
    type Tally = (
        usize,
        usize,
        BTreeMap<String, usize>,
        Option<Vec<(String, [f64; 3])>>,
    );
    let mut per: BTreeMap<usize, Tally> = BTreeMap::new();
    for r in &result.rollouts {
        let e = per.entry(r.context_index).or_default();
        e.0 += 1;
        if r.success {
            e.1 += 1;
            *e.2.entry(d3il_protocol::behaviour_name(task, &r.behaviour))
                .or_default() += 1;
        }
        if r.rollout_index == 0 {
            if let Some(t) = result.trace_of(r) {
                e.3 = Some(t.start_objects.clone());
            }
        }
    }
    per.into_iter()
        .filter_map(|(context_index, (n, ok, behaviours, objects))| {
            let mut dominant: Option<(String, usize)> = None;
            for (label, count) in behaviours {
                if dominant.as_ref().is_none_or(|d| count > d.1) {
                    dominant = Some((label, count));
                }
            }
            Some(StartState {
                context_index,
                objects: objects?,
                success_rate: ok as f64 / n.max(1) as f64,
                dominant_behaviour: dominant.map(|d| d.0),
            })
        })
        .collect()
}

/// A figure that says "no results yet" (or `message`) instead of empty axes,
/// the size and style of the other pictures.
pub fn no_data_svg(title: &str, message: &str) -> String {
    draw::no_data(title, message)
}

/// Objects whose name starts with `target` are fixed targets, not things the
/// robot moves.
pub(crate) fn is_target(name: &str) -> bool {
    name.starts_with("target")
}

/// "initial state 3, rollout 5": how errors and captions name a rollout.
pub(crate) fn rollout_name(r: &RolloutRecord) -> String {
    format!(
        "initial state {}, rollout {}",
        r.context_index, r.rollout_index
    )
}

fn bad(rollout: &str, reason: impl Into<String>) -> TablesError {
    TablesError::BadTrace {
        rollout: rollout.to_string(),
        reason: reason.into(),
    }
}

/// Unpacks a trace and checks that its arrays agree with each other: one TCP
/// position and one position per object for every state (the reset's and one
/// per step), one digest per step, finite landmarks.
pub(crate) fn unpack(trace: &RolloutTrace, rollout: &str) -> Result<UnpackedTrace, TablesError> {
    let t = trace.unpack().map_err(|e| bad(rollout, e.to_string()))?;
    let steps = t.actions.len();
    if t.tcp.len() != steps + 1 {
        return Err(bad(
            rollout,
            format!(
                "field `tcp` holds {} positions for {steps} steps; a trace holds one per state ({})",
                t.tcp.len(),
                steps + 1
            ),
        ));
    }
    if t.digests.len() != steps {
        return Err(bad(
            rollout,
            format!(
                "field `digests` holds {} digests for {steps} steps",
                t.digests.len()
            ),
        ));
    }
    for (name, path) in &t.objects {
        if path.len() != steps + 1 {
            return Err(bad(
                rollout,
                format!(
                    "field `objects.xy` of `{name}` holds {} positions for {steps} steps; a trace holds one per state ({})",
                    path.len(),
                    steps + 1
                ),
            ));
        }
    }
    checked_landmarks(trace, rollout)?;
    Ok(t)
}

fn checked_landmarks<'a>(
    trace: &'a RolloutTrace,
    rollout: &str,
) -> Result<&'a [Landmark], TablesError> {
    for l in &trace.landmarks {
        let finite = l.center.iter().chain(&l.half).all(|v| v.is_finite());
        if !finite || l.half.iter().any(|h| *h < 0.0) {
            return Err(bad(
                rollout,
                format!(
                    "field `landmarks` holds `{}` with centre {:?} and half extents {:?}",
                    l.label, l.center, l.half
                ),
            ));
        }
    }
    Ok(&trace.landmarks)
}

/// The points before the first one that is not finite (a simulation that
/// became unstable), and the index of that state if there is one.
pub(crate) fn finite_prefix<const N: usize>(pts: &[[f32; N]]) -> (Vec<[f64; N]>, Option<usize>) {
    let cut = pts.iter().position(|p| p.iter().any(|v| !v.is_finite()));
    let end = cut.unwrap_or(pts.len());
    let out = pts[..end]
        .iter()
        .map(|p| std::array::from_fn(|i| f64::from(p[i])))
        .collect();
    (out, cut)
}
