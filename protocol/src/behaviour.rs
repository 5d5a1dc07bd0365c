//! Where the tasks' layouts and behaviours are named once for everyone: the
//! Avoiding obstacle field (the evaluator builds its scene and mode detector
//! from it, the figures draw it) and readable names of the behaviour values
//! the evaluator stores per rollout (pages, plots and the CLI show these).

use crate::TaskId;
use serde_json::Value;

/// Avoiding's obstacle field (docs/original-d3il.md §10.2.1).
pub mod avoiding {
    /// x of the field's centre line.
    pub const MID_X: f64 = 0.5;
    /// Lateral spacing of the obstacles.
    pub const OFFSET: f64 = 0.075;
    pub const FIRST_ROW_Y: f64 = -0.1;
    pub const ROW_SPACING: f64 = 0.18;

    /// y of obstacle row `k` (0, 1, 2; 2.5 is the finish line).
    pub fn row_y(k: f64) -> f64 {
        FIRST_ROW_Y + k * ROW_SPACING
    }

    /// Finish line y (−0.1 + 2.5·0.18 = 0.35).
    pub fn finish_y() -> f64 {
        row_y(2.5)
    }

    /// One cylinder of the field.
    #[derive(Debug, Clone, Copy, PartialEq)]
    pub struct Obstacle {
        pub name: &'static str,
        pub x: f64,
        pub y: f64,
        pub radius: f64,
        pub half_length: f64,
    }

    /// The six cylinders, row by row.
    pub fn obstacles() -> [Obstacle; 6] {
        let o = |name, x, k, radius, half_length| Obstacle {
            name,
            x,
            y: row_y(k),
            radius,
            half_length,
        };
        [
            o("l1_obs", MID_X, 0.0, 0.03, 0.07),
            o("l2_top_obs", MID_X - OFFSET, 1.0, 0.025, 0.1),
            o("l2_bottom_obs", MID_X + OFFSET, 1.0, 0.025, 0.1),
            o("l3_top_obs", MID_X - 2.0 * OFFSET, 2.0, 0.025, 0.1),
            o("l3_mid_obs", MID_X, 2.0, 0.025, 0.1),
            o("l3_bottom_obs", MID_X + 2.0 * OFFSET, 2.0, 0.025, 0.1),
        ]
    }

    /// Readable name of a mode-bit vector (9 bits: 2 for row 1, 3 for row 2,
    /// 4 for row 3; docs/original-d3il.md §10.2.6): the gap taken in each row,
    /// numbered from the smallest x, e.g. `1-2-3`; `x` for a row not passed.
    pub fn path_name(bits: &[f64]) -> Option<String> {
        if bits.len() != 9 {
            return None;
        }
        let gap = |r: std::ops::Range<usize>| {
            let set: Vec<usize> = r.clone().filter(|&i| bits[i] >= 0.5).collect();
            match set.as_slice() {
                [] => "x".to_string(),
                [i] => (i - r.start + 1).to_string(),
                more => more
                    .iter()
                    .map(|i| (i - r.start + 1).to_string())
                    .collect::<Vec<_>>()
                    .join("+"),
            }
        };
        Some(format!("{}-{}-{}", gap(0..2), gap(2..5), gap(5..9)))
    }
}

/// Sorting's colour order from its packed code (docs/original-d3il.md §11.1.6:
/// the first X slots as bits, red 0, blue 1, most significant bit first:
/// Sorting-2 64 = `RB`, 128 = `BR`). `None` when `task` is not Sorting or the
/// code is not a complete sequence (X/2 of each colour, nothing after the X
/// bits; an unsorted slot also counts as 1, so e.g. 192 on Sorting-2 is
/// "nothing sorted", not `BB`).
pub fn sorting_order(task: TaskId, code: u64) -> Option<String> {
    let n: u32 = match task {
        TaskId::Sorting2 => 2,
        TaskId::Sorting4 => 4,
        TaskId::Sorting6 => 6,
        _ => return None,
    };
    let used = (0xFFu64 << (8 - n)) & 0xFF;
    if code & !used != 0 || code.count_ones() != n / 2 {
        return None;
    }
    Some(
        (0..n)
            .map(|i| if code >> (7 - i) & 1 == 1 { 'B' } else { 'R' })
            .collect(),
    )
}

/// A readable name for a stored behaviour value: Avoiding's gaps (`1-2-3`),
/// Sorting's colour order (`RB`), Stacking's registration order (`rgb`),
/// the integer mode of Aligning and Pushing (`0`, not `0.0`), `none` for no
/// behaviour.
pub fn behaviour_name(task: TaskId, v: &Value) -> String {
    match v {
        Value::Null => "none".into(),
        Value::String(s) if s.is_empty() => "none".into(),
        Value::String(s) => s.clone(),
        Value::Array(a) if task == TaskId::Avoiding => {
            let bits: Vec<f64> = a.iter().filter_map(Value::as_f64).collect();
            match (bits.len() == a.len())
                .then(|| avoiding::path_name(&bits))
                .flatten()
            {
                Some(n) => n,
                None => v.to_string(),
            }
        }
        Value::Number(n) => {
            let int = n.as_u64().or_else(|| {
                n.as_f64()
                    .filter(|f| f.fract() == 0.0 && *f >= 0.0)
                    .map(|f| f as u64)
            });
            match int {
                Some(i) => sorting_order(task, i).unwrap_or_else(|| i.to_string()),
                None => n
                    .as_i64()
                    .map(|i| i.to_string())
                    .unwrap_or_else(|| n.to_string()),
            }
        }
        other => other.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn names_are_readable() {
        let bits = json!([1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0]);
        assert_eq!(behaviour_name(TaskId::Avoiding, &bits), "1-2-3");
        let cut = json!([0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]);
        assert_eq!(behaviour_name(TaskId::Avoiding, &cut), "2-x-x");
        // docs/original-d3il.md §11.1.6: Sorting-2 RB = 64, BR = 128.
        assert_eq!(behaviour_name(TaskId::Sorting2, &json!(64)), "RB");
        assert_eq!(behaviour_name(TaskId::Sorting2, &json!(128)), "BR");
        assert_eq!(
            behaviour_name(TaskId::Sorting4, &json!(0b1001_0000)),
            "BRRB"
        );
        assert_eq!(behaviour_name(TaskId::Sorting6, &json!(28)), "RRRBBB");
        // Not a complete sequence (nothing sorted): the code itself.
        assert_eq!(behaviour_name(TaskId::Sorting2, &json!(192)), "192");
        assert_eq!(behaviour_name(TaskId::Stacking, &json!("rgb")), "rgb");
        assert_eq!(behaviour_name(TaskId::Stacking, &json!("")), "none");
        assert_eq!(behaviour_name(TaskId::Pushing, &json!(2.0)), "2");
        assert_eq!(behaviour_name(TaskId::Pushing, &json!(-1)), "-1");
        assert_eq!(behaviour_name(TaskId::Aligning, &Value::Null), "none");
    }

    #[test]
    fn the_field_is_the_documented_one() {
        let o = avoiding::obstacles();
        assert_eq!((o[0].x, o[0].y), (0.5, -0.1));
        assert!((o[5].x - 0.65).abs() < 1e-12 && (o[5].y - 0.26).abs() < 1e-12);
        assert!((avoiding::finish_y() - 0.35).abs() < 1e-12);
    }
}
