//! The readable behaviour names the pages, plots and CLI show
//! (`d3il_protocol::behaviour_name`) decode exactly what the evaluator's
//! detectors encode: every complete Sorting colour sequence round-trips
//! through `pack_code`, and every Avoiding path's mode bits name its gaps.

use d3il_evaluator::tasks::avoiding::path_choice;
use d3il_evaluator::tasks::sorting::{is_sequence_code, pack_code, parse_order};
use d3il_protocol::{behaviour_name, TaskId};
use serde_json::json;

#[test]
fn sorting_orders_round_trip_through_the_packed_code() {
    for (task, n) in [
        (TaskId::Sorting2, 2usize),
        (TaskId::Sorting4, 4),
        (TaskId::Sorting6, 6),
    ] {
        let mut seen = 0;
        for bits in 0u32..(1 << n) {
            let order: String = (0..n)
                .map(|i| {
                    if bits >> (n - 1 - i) & 1 == 1 {
                        'B'
                    } else {
                        'R'
                    }
                })
                .collect();
            let slots: Vec<_> = parse_order(&order).unwrap().into_iter().map(Some).collect();
            let code = pack_code(&slots);
            let name = behaviour_name(task, &json!(code));
            if is_sequence_code(code, n) {
                assert_eq!(name, order, "{task:?} code {code}");
                seen += 1;
            } else {
                assert_eq!(name, code.to_string(), "{task:?}: {order} is no behaviour");
            }
        }
        // C(n, n/2) behaviours: 2, 6, 20.
        assert_eq!(seen, [2, 6, 20][n / 2 - 1]);
    }
}

#[test]
fn avoiding_paths_are_named_by_their_gaps() {
    for path in 0..24 {
        let (a, b, c) = path_choice(path).unwrap();
        let mut bits = [0.0f64; 9];
        bits[a] = 1.0;
        bits[2 + b] = 1.0;
        bits[5 + c] = 1.0;
        assert_eq!(
            behaviour_name(TaskId::Avoiding, &json!(bits.to_vec())),
            format!("{}-{}-{}", a + 1, b + 1, c + 1)
        );
    }
}
