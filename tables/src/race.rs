//! The race page's figure (`/races/{id}`): a sequential race drawn
//! pair by pair. Above, the walk of wins minus losses (discordant pairs A
//! won minus those B won) against the boundary that decides it
//! (`d3il_metrics::horizon::CalibratedBoundary`: `±⌈z √d⌉` after `d`
//! discordant pairs, the last look's bound at the horizon); below, the
//! two-sided e-value's path (`d3il_metrics::sequential::PairedEProcess`,
//! log scale) against `1/α`, the rule when there is no horizon.

use crate::panels::chart;
use crate::plot::{canvas, Overlay};
use crate::TablesError;
use d3il_metrics::horizon::{CalibratedBoundary, MAX_HORIZON};
use d3il_metrics::sequential::PairedEProcess;
use plotters::prelude::*;

/// One pair's point of the race's paths.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RaceStep {
    /// 1-based pair number.
    pub pair: usize,
    /// Discordant pairs won by A minus those won by B.
    pub walk: i64,
    /// `|w − l|` from which the boundary decides at this pair (`None`: it
    /// cannot yet, or there is no calibrated boundary).
    pub bound: Option<u64>,
    pub e_value: f64,
}

/// The race's paths pair by pair (`pairs`: `(A succeeded, B succeeded)` in
/// the order the test saw them; `horizon`: the protocol's most pairs).
pub fn race_steps(pairs: &[(bool, bool)], alpha: f64, horizon: usize) -> Vec<RaceStep> {
    let boundary = (1..=MAX_HORIZON)
        .contains(&horizon)
        .then(|| CalibratedBoundary::new(alpha, horizon));
    let mut e = PairedEProcess::new();
    pairs
        .iter()
        .enumerate()
        .map(|(i, &(a, b))| {
            e.observe(a, b);
            let (w, l) = e.discordant();
            let d = (w + l) as usize;
            let pair = i + 1;
            let bound = boundary.as_ref().and_then(|bd| {
                if pair == horizon {
                    bd.last_bound(d)
                } else if pair < horizon {
                    bd.running_bound(d)
                } else {
                    None
                }
            });
            RaceStep {
                pair,
                walk: w as i64 - l as i64,
                bound,
                e_value: e.e_value(),
            }
        })
        .collect()
}

const WALK: RGBColor = RGBColor(31, 119, 180);
const BOUND: RGBColor = RGBColor(214, 39, 40);
const EVALUE: RGBColor = RGBColor(44, 160, 44);

/// The figure (SVG) of [`race_steps`]: the walk against its boundary, the
/// e-value's path against `1/α`.
pub fn race_svg(pairs: &[(bool, bool)], alpha: f64, horizon: usize) -> Result<String, TablesError> {
    let steps = race_steps(pairs, alpha, horizon);
    let n = steps.len();
    // The axis runs to the horizon (where the last look is), or to the
    // pairs seen beyond it.
    let x_max = n.max(horizon.min(5_000)).max(1) as f64;
    let reach = steps
        .iter()
        .map(|s| (s.walk.unsigned_abs()).max(s.bound.unwrap_or(0)))
        .max()
        .unwrap_or(0)
        .max(3) as f64;
    let threshold = (1.0 / alpha).log10();
    let top = steps
        .iter()
        .map(|s| s.e_value.max(1e-300).log10())
        .fold(threshold, f64::max);
    let bottom = steps
        .iter()
        .map(|s| s.e_value.max(1e-300).log10())
        .fold(-1.0f64, f64::min);
    let (w, h) = (640u32, 520u32);
    let mut ov = Overlay::default();
    let buf = canvas((w, h), |root| {
        let (upper, lower) = root.split_vertically(300);
        let walk_chart = chart(
            &upper,
            "Wins minus losses against the boundary",
            0.0..x_max,
            -(reach + 1.0)..reach + 1.0,
            "pair",
            "w − l (discordant pairs)",
        )?;
        let px = |x: f64, y: f64| {
            let (a, b) = walk_chart.backend_coord(&(x, y));
            (a as f64, b as f64)
        };
        // The boundary as a step line, where it can decide.
        let (mut up, mut down) = (Vec::new(), Vec::new());
        for s in &steps {
            match s.bound {
                Some(b) => {
                    up.push(px(s.pair as f64, b as f64));
                    down.push(px(s.pair as f64, -(b as f64)));
                }
                None => {
                    ov.polyline("lines", &up, BOUND, 1.5, true);
                    ov.polyline("lines", &down, BOUND, 1.5, true);
                    up.clear();
                    down.clear();
                }
            }
        }
        ov.polyline("lines", &up, BOUND, 1.5, true);
        ov.polyline("lines", &down, BOUND, 1.5, true);
        let mut path = vec![px(0.0, 0.0)];
        path.extend(steps.iter().map(|s| px(s.pair as f64, s.walk as f64)));
        ov.polyline("lines", &path, WALK, 2.0, false);
        if let Some(last) = steps.last() {
            ov.marker(
                "points",
                px(last.pair as f64, last.walk as f64),
                crate::plot::Shape::Circle,
                3.5,
                WALK,
            );
        }
        let e_chart = chart(
            &lower,
            "e-value (log10) against 1/α",
            0.0..x_max,
            (bottom - 0.2)..(top + 0.3),
            "pair",
            "log10 e-value",
        )?;
        let pe_ = |x: f64, y: f64| {
            let (a, b) = e_chart.backend_coord(&(x, y));
            (a as f64, b as f64)
        };
        ov.line(
            "lines",
            pe_(0.0, threshold),
            pe_(x_max, threshold),
            BOUND,
            1.2,
        );
        let mut epath = vec![pe_(0.0, 0.0)];
        epath.extend(
            steps
                .iter()
                .map(|s| pe_(s.pair as f64, s.e_value.max(1e-300).log10())),
        );
        ov.polyline("lines", &epath, EVALUE, 2.0, false);
        Ok(())
    })?;
    Ok(ov.splice(buf))
}
