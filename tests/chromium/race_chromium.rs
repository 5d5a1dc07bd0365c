//! Headless Chromium draws the race page (`/races/{id}`) of the real
//! `d3il serve`: a finished Pushing race stored as a race slot stores it (the
//! store's claim and completion), its report from the real sequential test.
//! A script measures the figure as Chromium laid it out: the walk of wins
//! minus losses stays inside the boundary until the pair at which the race
//! decided and meets it there; the e-value's path ends at the same pair, on
//! the side of 1/α its value is on; every path is drawn with a size inside
//! the figure. The fixed-size comparison's line is on the page.

use crate::D3IL;
use d3il_metrics::sequential::SequentialComparison;
use d3il_protocol::race::{pairs_of, RaceReport};
use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use d3il_server::store::{NewPolicy, NewRace, NewSubmission, Store};
use d3il_test_support::chromium::{chromium, dump_dom, serve_with_script};
use d3il_test_support::server::*;

/// The pairs of a race A wins (as server/tests/app/compare_page.rs's), its
/// horizon 30 initial states.
const CODES: &str = "a1a0aab1aa0aaa1aab0aaaa1aaaaaa";

/// The race through the real test up to its decision: (report, pairs used).
fn report() -> (RaceReport, usize) {
    let pairs = pairs_of(CODES).unwrap();
    let mut test = SequentialComparison::with_horizon(0.05, None, pairs.len());
    for &p in &pairs {
        if test.observe_pair(p).is_some() {
            break;
        }
    }
    let at = test
        .decided_at()
        .expect("A wins this race before its horizon") as usize;
    let seen = &CODES[..at];
    let e = test.eprocess();
    let r = RaceReport {
        task: TaskId::Pushing,
        protocol: ProtocolKind::Paper,
        seed: 0,
        alpha: 0.05,
        delta: None,
        pair: "initial state (its rollout 0)".into(),
        decision: test.decision().map(|d| d.to_string()),
        decided_at: Some(at as u64),
        e_value: e.e_value(),
        p_value: e.p_value(),
        discordant: e.discordant(),
        difference_interval: test.difference_interval(),
        rate_a: (seen.matches('a').count() + seen.matches('1').count()) as f64 / at as f64,
        rate_b: (seen.matches('b').count() + seen.matches('1').count()) as f64 / at as f64,
        pairs_used: e.pairs(),
        pairs_full: pairs.len() as u64,
        states_used: at,
        states_full: pairs.len(),
        rollouts_used: 2 * at * 16,
        rollouts_full: 2 * pairs.len() * 16,
        rollouts_simulated: 2 * at * 16,
        fixed_p_value: d3il_metrics::sign_test::FixedPairedTest::new(0.05)
            .p_value(e.discordant().0, e.discordant().1),
        fixed_pairs_for_power_90: None,
        seconds: 1.0,
        policy_calls: 1,
        outcomes: seen.into(),
    };
    (r, at)
}

/// Two Pushing submissions and the finished race between them.
fn seed(db: &std::path::Path, report: &RaceReport) -> i64 {
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    rt.block_on(async {
        let store = Store::open(db).await.expect("open store");
        let token = store.create_token("racer").await.expect("token");
        let who = store
            .authenticate(&token)
            .await
            .expect("authenticate")
            .expect("the racer");
        let mut ids = vec![];
        for name in ["Alpha", "Beta"] {
            let method_id = d3il_test_support::server::method_id(&store, name).await;
            let id = store
                .create_submission(
                    &NewSubmission {
                        method_id,
                        submitter_id: Some(who.id),
                        task: TaskId::Pushing,
                        obs_type: ObsType::State,
                        training_seed: 0,
                        data_fraction: 1.0,
                        protocol: ProtocolKind::Paper,
                        policy: NewPolicy::Remote {
                            url: "http://127.0.0.1:9/".into(),
                            secret: None,
                        },
                        manifest_json: r#"{"task": "pushing", "obs_type": "state", "history": 1, "horizon": 1, "execute": 1}"#.into(),
                        simulated_once: None,
                    },
                    3,
                )
                .await
                .expect("submission");
            ids.push(id);
        }
        let race = store
            .create_race(&NewRace {
                submission_a: ids[0],
                submission_b: ids[1],
                submitter_id: who.id,
                task: d3il_protocol::TaskId::Pushing,
                protocol: d3il_protocol::ProtocolKind::Paper,
                seed: 0,
                alpha: report.alpha,
                delta: None,
            })
            .await
            .expect("race");
        let claimed = store
            .claim_race("test", 3600)
            .await
            .expect("claim")
            .expect("the race waits");
        assert_eq!(claimed.id, race);
        store
            .race_completed(race, &serde_json::to_string(report).unwrap())
            .await
            .expect("complete");
        race
    })
}

/// What the script reports of one path: its colour, dashed or not, its
/// points in the SVG's coordinates and its rendered box.
#[derive(serde::Deserialize, Debug)]
struct Path {
    stroke: String,
    dashed: bool,
    points: Vec<[f64; 2]>,
    width: f64,
    height: f64,
    inside: bool,
}

#[derive(serde::Deserialize, Debug)]
struct Figure {
    paths: Vec<Path>,
    /// The 1/α line's y (the one straight line in the boundary's colour).
    threshold_y: Option<f64>,
}

#[test]
fn chromium_draws_the_race_walk_against_its_boundary_and_the_e_value_path() {
    let browser = chromium();
    let dir = TempDir::new("race-chromium");
    let db = dir.path().join("lb.sqlite");
    let (report, at) = report();
    let race = seed(&db, &report);
    let server = D3IL.serve(&db, &["--workers", "0"]);
    let (s, page) = server.get_text_blocking(&format!("/races/{race}"));
    assert_eq!(s, 200, "{page}");
    assert!(
        page.contains(&format!("Fixed-size comparison of the {at} pairs used")),
        "{page}"
    );
    // The page, its stylesheet from the server, and a script that reads the
    // figure as laid out once everything has loaded (the site's pages run no
    // script).
    let script = r#"<script>window.addEventListener('load', function () {
        var fig = document.querySelector('#race-walk svg');
        var out = {paths: [], threshold_y: null};
        if (fig) {
          var fb = fig.getBoundingClientRect();
          fig.querySelectorAll('polyline').forEach(function (p) {
            var b = p.getBoundingClientRect();
            var pts = [];
            for (var i = 0; i < p.points.numberOfItems; i++) {
              var q = p.points.getItem(i); pts.push([q.x, q.y]);
            }
            out.paths.push({stroke: p.getAttribute('stroke'), dashed: p.hasAttribute('stroke-dasharray'),
              points: pts, width: b.width, height: b.height,
              inside: b.left >= fb.left - 1 && b.right <= fb.right + 1 && b.top >= fb.top - 1 && b.bottom <= fb.bottom + 1});
          });
          fig.querySelectorAll('line').forEach(function (l) {
            if (l.getAttribute('stroke') === '#d62728') { out.threshold_y = parseFloat(l.getAttribute('y1')); }
          });
        }
        var r = document.createElement('pre'); r.id = 'race-report';
        r.textContent = 'FIG' + 'URE:' + JSON.stringify(out) + ':E' + 'ND';
        document.body.appendChild(r);});</script>"#;
    let url = serve_with_script(&page, &server.base, script);
    let dom = dump_dom(
        &browser,
        &url,
        &dir.path().join("profile"),
        &["--virtual-time-budget=5000"],
    );
    let json = dom
        .split("FIGURE:")
        .nth(1)
        .and_then(|x| x.split(":END").next())
        .unwrap_or_else(|| panic!("no figure report in the DOM: {dom}"));
    let fig: Figure = serde_json::from_str(&json.replace("&quot;", "\""))
        .unwrap_or_else(|e| panic!("{e}: {json}"));

    let of =
        |stroke: &str| -> Vec<&Path> { fig.paths.iter().filter(|p| p.stroke == stroke).collect() };
    // Blue: the walk, from pair 0 to the decision.
    let walk = of("#1f77b4");
    assert_eq!(walk.len(), 1, "{fig:?}");
    let walk = walk[0];
    assert_eq!(walk.points.len(), at + 1, "{walk:?}");
    // Red, dashed: the boundary above and below.
    let bounds = of("#d62728");
    assert!(
        bounds.iter().all(|b| b.dashed) && bounds.len() >= 2,
        "{bounds:?}"
    );
    // Green: the e-value's path, over the same pairs.
    let evalue = of("#2ca02c");
    assert_eq!(evalue.len(), 1, "{fig:?}");
    let evalue = evalue[0];
    assert_eq!(evalue.points.len(), at + 1, "{evalue:?}");
    for p in std::iter::once(walk)
        .chain(bounds.iter().copied())
        .chain([evalue])
    {
        assert!(p.inside, "drawn outside the figure: {p:?}");
        assert!(
            p.width > 0.0 || p.height > 0.0,
            "drawn without a size: {p:?}"
        );
    }
    assert!(
        walk.width > 100.0 && evalue.width > 100.0,
        "{walk:?} {evalue:?}"
    );

    // The walk against the upper boundary, pair by pair (A won: upward, so
    // a smaller y): inside it before the decision, on or beyond it at it.
    let upper = |x: f64| -> Option<f64> {
        bounds
            .iter()
            .flat_map(|b| b.points.iter())
            .filter(|q| (q[0] - x).abs() < 0.05)
            .map(|q| q[1])
            .reduce(f64::min)
    };
    let (last, before) = walk.points.split_last().unwrap();
    let bound_at_last = upper(last[0]).expect("the boundary at the deciding pair");
    assert!(
        last[1] <= bound_at_last + 0.05,
        "the walk ends at y {} but the boundary is at {bound_at_last}",
        last[1]
    );
    let mut compared = 0;
    for q in before {
        if let Some(b) = upper(q[0]) {
            assert!(
                q[1] > b + 0.05,
                "the walk met the boundary before pair {at}: {q:?} at {b}"
            );
            compared += 1;
        }
    }
    assert!(
        compared > 3,
        "the boundary spans the race: {compared} pairs"
    );
    // The e-value's path ends at the deciding pair, on the side of 1/α its
    // value is on (here it did not decide: the boundary did).
    let e_last = evalue.points.last().unwrap();
    assert!((e_last[0] - last[0]).abs() < 0.5, "{e_last:?} {last:?}");
    let threshold = fig.threshold_y.expect("the 1/α line");
    assert_eq!(
        e_last[1] < threshold,
        report.e_value >= 1.0 / report.alpha,
        "e-value {} drawn at y {} against 1/α at {threshold}",
        report.e_value,
        e_last[1]
    );
}
