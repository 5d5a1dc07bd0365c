//! The race page's figure draws the rule that decides: the pair where the
//! walk first meets its boundary is the pair the sequential comparison
//! decided at, and the e-value path is the test's.

use d3il_metrics::sequential::SequentialComparison;
use d3il_tables::race::{race_steps, race_svg};

fn pairs(codes: &str) -> Vec<(bool, bool)> {
    d3il_protocol::race::pairs_of(codes).unwrap()
}

#[test]
fn the_walk_meets_its_boundary_where_the_comparison_decided() {
    // A Pushing-like race: 30 initial states, A wins most discordant pairs.
    let codes = "a1a0aab1aa0aaa1aab0aaaa1aaaaaa";
    let p = pairs(codes);
    let mut test = SequentialComparison::with_horizon(0.05, None, 30);
    for &x in &p {
        test.observe_pair(x);
    }
    let decided = test.decided_at().expect("A wins clearly") as usize;
    let steps = race_steps(&p, 0.05, 30);
    let first = steps
        .iter()
        .find(|s| s.bound.is_some_and(|b| s.walk.unsigned_abs() >= b))
        .expect("the walk meets the boundary");
    assert_eq!(first.pair, decided, "{steps:?}");
    // The e-value path is the test's.
    assert_eq!(steps.last().unwrap().e_value, test.eprocess().e_value());
    let svg = race_svg(&p, 0.05, 30).unwrap();
    assert!(roxmltree::Document::parse(&svg).is_ok());
    // The walk, the two boundary lines and the e-value path.
    assert!(svg.matches("<polyline").count() >= 4, "{svg}");
}

#[test]
fn pairs_beyond_the_horizon_have_no_boundary_and_an_undecided_race_draws() {
    let steps = race_steps(&pairs("ab10ab"), 0.05, 4);
    assert!(steps[4].bound.is_none() && steps[5].bound.is_none());
    assert_eq!(
        steps.iter().map(|s| s.walk).collect::<Vec<_>>(),
        [1, 0, 0, 0, 1, 0]
    );
    assert!(race_svg(&pairs("ab10ab"), 0.05, 4).is_ok());
    assert_eq!(d3il_protocol::race::pairs_of("a?"), Err('?'));
}
