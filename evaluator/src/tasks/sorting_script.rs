//! The scripted Sorting policy (a reference for tests and benchmarks).

use super::*;

/// Scripted reference policy: pushes the boxes over the platform's +y edge
/// into their bins, one at a time, in a chosen colour order. Among the boxes
/// of the colour due next it takes the one closest to the edge (largest y),
/// reaches it around the outside of the box field, and pushes it toward its
/// bin with feedback on the (stale) box position from the observation.
#[derive(Debug, Clone)]
pub struct SortingScript {
    order: Vec<Colour>,
    next: usize,
    phase: Phase,
    current: Option<usize>,
    waypoints: Vec<[f64; 2]>,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Phase {
    Choose,
    Travel,
    Push,
    Done,
}

/// Rod radius + box half-diagonal + margin: where the rod waits behind a box.
const PRE_PUSH: f64 = 0.075;
/// Lanes around the box field (boxes occupy x ∈ [0.358, 0.692], y ∈ [−0.192, 0.142]).
const BACK_LANE_Y: f64 = -0.215;
const FRONT_LANE_Y: f64 = 0.17;
const LEFT_LANE_X: f64 = 0.33;
const RIGHT_LANE_X: f64 = 0.72;
/// A box whose centre passed this y has gone over the near wall.
const FALLEN_Y: f64 = 0.235;

impl SortingScript {
    /// `order` is the colour sequence to sort, e.g. "RB" or "BRRB"; it must
    /// contain each colour X/2 times for Sorting-X.
    pub fn new(order: &str) -> Option<SortingScript> {
        Some(SortingScript {
            order: parse_order(order)?,
            next: 0,
            phase: Phase::Choose,
            current: None,
            waypoints: Vec::new(),
        })
    }

    fn boxes(obs: &[f32]) -> Vec<([f64; 2], Colour)> {
        let n = (obs.len() - 4) / 3;
        (0..n)
            .map(|k| {
                let b = &obs[4 + 3 * k..];
                let c = if k < n / 2 { Colour::Red } else { Colour::Blue };
                ([b[0] as f64, b[1] as f64], c)
            })
            .collect()
    }

    /// Policy input [desired xy, measured xy, boxes...] -> xy delta.
    pub fn act(&mut self, obs: &[f32]) -> [f32; 2] {
        let d = [obs[0] as f64, obs[1] as f64];
        let boxes = Self::boxes(obs);
        let toward = |target: [f64; 2], max: f64| -> [f32; 2] {
            let e = [target[0] - d[0], target[1] - d[1]];
            let n = (e[0] * e[0] + e[1] * e[1]).sqrt();
            let s = if n > max { max / n } else { 1.0 };
            [(e[0] * s) as f32, (e[1] * s) as f32]
        };
        for _ in 0..4 {
            match self.phase {
                Phase::Done => return [0.0, 0.0],
                Phase::Choose => {
                    let Some(&colour) = self.order.get(self.next) else {
                        self.phase = Phase::Done;
                        continue;
                    };
                    let pick = boxes
                        .iter()
                        .enumerate()
                        .filter(|(_, (p, c))| *c == colour && p[1] < 0.2)
                        .max_by(|a, b| a.1 .0[1].total_cmp(&b.1 .0[1]))
                        .map(|(i, _)| i);
                    let Some(i) = pick else {
                        self.next += 1;
                        continue;
                    };
                    self.current = Some(i);
                    let (b, c) = boxes[i];
                    let pre = pre_push_point(b, c.bin());
                    // Around the outside: front lane if we are at the edge,
                    // then the nearer side lane, the back lane, and up to the box.
                    let side = if d[0] < 0.525 {
                        LEFT_LANE_X
                    } else {
                        RIGHT_LANE_X
                    };
                    let mut w = Vec::new();
                    if d[1] > FRONT_LANE_Y - 0.03 {
                        w.push([d[0], FRONT_LANE_Y]);
                        w.push([side, FRONT_LANE_Y]);
                    } else if d[1] > BACK_LANE_Y + 0.01 {
                        w.push([side, d[1]]);
                    }
                    w.push([side, BACK_LANE_Y]);
                    w.push([pre[0], BACK_LANE_Y]);
                    w.push(pre);
                    self.waypoints = w;
                    self.phase = Phase::Travel;
                }
                Phase::Travel => {
                    // Keep the final approach point on the moving box.
                    if let Some(i) = self.current {
                        let (b, c) = boxes[i];
                        if self.waypoints.len() == 1 {
                            self.waypoints[0] = pre_push_point(b, c.bin());
                        }
                    }
                    match self.waypoints.first() {
                        Some(&w) if dist2(&w, &d) > 0.004 => return toward(w, 0.008),
                        Some(_) => {
                            self.waypoints.remove(0);
                        }
                        None => self.phase = Phase::Push,
                    }
                }
                Phase::Push => {
                    let Some(i) = self.current else {
                        self.phase = Phase::Choose;
                        continue;
                    };
                    let (b, c) = boxes[i];
                    if b[1] > FALLEN_Y {
                        self.next += 1;
                        self.phase = Phase::Choose;
                        continue;
                    }
                    let goal = c.bin();
                    let u = unit([goal[0] - b[0], goal[1] - b[1]]);
                    // Aim at a point just inside the box's back face on the
                    // line to the bin; the lateral part steers the box.
                    let aim = [b[0] - u[0] * 0.02, b[1] - u[1] * 0.02];
                    return toward(aim, 0.005);
                }
            }
        }
        [0.0, 0.0]
    }
}

fn unit(v: [f64; 2]) -> [f64; 2] {
    let n = (v[0] * v[0] + v[1] * v[1]).sqrt().max(1e-9);
    [v[0] / n, v[1] / n]
}

fn pre_push_point(b: [f64; 2], goal: [f64; 2]) -> [f64; 2] {
    let u = unit([goal[0] - b[0], goal[1] - b[1]]);
    [b[0] - u[0] * PRE_PUSH, b[1] - u[1] * PRE_PUSH]
}
