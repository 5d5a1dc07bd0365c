//! Closed-loop regression tests (issue 32, item 4) on the policies of
//! tests/data/reference-closed-loop (copied from ../shared; README there):
//! align_bc and push_bc_noise evaluated here under the paper protocol
//! against what each did in the ORIGINAL simulator (one rollout per
//! initial state), through the fidelity report's own functions
//! (`d3il_evaluator::fidelity::closed_loop`, what `d3il fidelity` prints).
//!
//! Numbers agree in distribution; state by state an outcome near a
//! decision boundary flips with the float32 rounding of the inference
//! engine alone (tract here, onnxruntime there), so the tests check
//! intervals both ways, and floors for the per-state agreement and for how
//! long the original's actions, replayed open-loop here, follow the
//! original's TCP. The floors are today's figures (tests/data/closed-loop-floor.json,
//! rewritten by running this file with D3IL_WRITE_CLOSED_LOOP_FLOOR=1 after
//! a change that is meant to move them: say why in the commit).
//!
//! Cost: align_bc under the paper protocol (60 states; deterministic, so
//! one simulation each), push_bc_noise on the paper protocol's 30 states
//! with 4 rollouts each instead of 16 (120 rollouts: its 480 cost about
//! 340 s of CPU, the largest single item of CI's test phase; 4 per state
//! keep both interval checks and the per-state floors meaningful) and 90
//! open-loop replays, computed once for the three tests. `d3il fidelity`
//! still runs the whole paper protocol.

use d3il_evaluator::fidelity::closed_loop::{compare_sampled, TCP_TOLERANCE_M};
use d3il_protocol::fidelity::{FidelityMode, PolicyFidelity};
use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// The policies and the rollouts per initial state they run here (`None`:
/// the paper protocol's).
const POLICIES: [(&str, Option<usize>); 2] = [("align_bc", None), ("push_bc_noise", Some(4))];

fn data() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data")
}

/// Both policies, evaluated once for all tests of this file.
fn results() -> &'static Vec<PolicyFidelity> {
    static R: OnceLock<Vec<PolicyFidelity>> = OnceLock::new();
    R.get_or_init(|| {
        let t0 = std::time::Instant::now();
        let dir = data().join("reference-closed-loop");
        let r: Vec<PolicyFidelity> = POLICIES
            .iter()
            .map(|(name, per)| compare_sampled(&dir, name, FidelityMode::Full, *per).expect(name))
            .collect();
        eprintln!(
            "closed loop computed in {:.0} s",
            t0.elapsed().as_secs_f64()
        );
        if std::env::var_os("D3IL_WRITE_CLOSED_LOOP_FLOOR").is_some() {
            write_floor(&r);
        }
        r
    })
}

fn floor_path() -> PathBuf {
    data().join("closed-loop-floor.json")
}

/// One policy's floors, in the file's order.
#[derive(serde::Serialize)]
struct Floor {
    success_agreement: f64,
    behaviour_agreement: f64,
    /// By initial state, in numeric order.
    steps_within: BTreeMap<usize, usize>,
}

/// The floor file: `about`, then the policies by name.
#[derive(serde::Serialize)]
struct FloorFile {
    about: &'static str,
    #[serde(flatten)]
    policies: BTreeMap<String, Floor>,
}

/// Today's figures as the floor file (serialized straight from the typed
/// file, so its keys keep this order: a rewrite changes only what moved).
fn write_floor(r: &[PolicyFidelity]) {
    let file = FloorFile {
        about: "Floors of tests/closed_loop.rs: per policy, the per-state agreement with the original (shares of our rollouts with the original's success / behaviour in the same initial state) and, per initial state, the env steps during which the original's actions replayed open-loop here keep our TCP within 1e-9 m of the original's. Written by D3IL_WRITE_CLOSED_LOOP_FLOOR=1 cargo test --test closed_loop.",
        policies: r
            .iter()
            .map(|p| {
                let floor = Floor {
                    success_agreement: p.success_agreement,
                    behaviour_agreement: p.behaviour_agreement,
                    steps_within: p
                        .open_loop
                        .iter()
                        .map(|e| (e.context, e.steps_within))
                        .collect(),
                };
                (p.name.clone(), floor)
            })
            .collect(),
    };
    std::fs::write(
        floor_path(),
        serde_json::to_string_pretty(&file).unwrap() + "\n",
    )
    .unwrap();
    eprintln!("wrote {}", floor_path().display());
}

fn floor() -> Value {
    serde_json::from_str(&std::fs::read_to_string(floor_path()).unwrap()).unwrap()
}

#[test]
fn success_rates_lie_inside_each_others_95_percent_intervals() {
    for p in results() {
        let (o, h) = (&p.original, &p.here);
        eprintln!(
            "{}: here {}/{} = {:.3} ({:.3}-{:.3}), original {}/{} = {:.3} ({:.3}-{:.3})",
            p.name,
            h.successes,
            h.rollouts,
            h.value,
            h.ci_low,
            h.ci_high,
            o.successes,
            o.rollouts,
            o.value,
            o.ci_low,
            o.ci_high
        );
        assert_eq!(p.contexts, if p.task == "aligning" { 60 } else { 30 });
        assert!(
            p.here_inside_original_interval,
            "{}: our rate {:.3} is outside the original's interval {:.3}-{:.3}",
            p.name, h.value, o.ci_low, o.ci_high
        );
        assert!(
            p.original_inside_here_interval,
            "{}: the original's rate {:.3} is outside our interval {:.3}-{:.3}",
            p.name, o.value, h.ci_low, h.ci_high
        );
    }
}

/// Floors measured on 26 November (commit of this test): align_bc keeps
/// the original's outcome on 47 of 60 initial states (0.783) and its
/// behaviour on 58 (0.967); push_bc_noise, whose noise is not the
/// original's, 278 of 480 rollouts (0.579) and 279 (0.581); since 29
/// November 4 rollouts per state: 75 of 120 (0.625) and 74 (0.617).
#[test]
fn per_state_agreement_does_not_fall_below_today() {
    let floor = floor();
    for p in results() {
        let f = &floor[&p.name];
        for (what, got) in [
            ("success_agreement", p.success_agreement),
            ("behaviour_agreement", p.behaviour_agreement),
        ] {
            let min = f[what].as_f64().unwrap();
            eprintln!("{} {what}: {got:.4} (floor {min:.4})", p.name);
            assert!(
                got >= min - 1e-12,
                "{}: {what} fell to {got:.4} from {min:.4}",
                p.name
            );
        }
    }
}

/// The original's actions replayed open-loop here follow the original's
/// TCP: per episode, the env steps during which ours stays within 1e-9 m
/// must not get shorter than today's. (Today: 59 of the 60 align_bc
/// episodes for the whole episode, among them 12 of the 13 whose closed
/// loop ends differently here, within 1.1e-10 m; push_bc_noise's leave at
/// 28-236 steps, once the rod pushes a box, except the 2 that never push.)
#[test]
fn original_actions_replayed_here_follow_the_original_tcp() {
    assert_eq!(TCP_TOLERANCE_M, 1e-9);
    let floor = floor();
    let mut shorter = vec![];
    for p in results() {
        let within = &floor[&p.name]["steps_within"];
        let whole = p.open_loop.iter().filter(|e| e.whole_episode).count();
        eprintln!(
            "{}: {whole} of {} episodes within 1e-9 m for the whole episode",
            p.name,
            p.open_loop.len()
        );
        for e in &p.open_loop {
            let min = within[e.context.to_string()].as_u64().unwrap() as usize;
            eprintln!(
                "  {} initial state {:>2}: within 1e-9 m for {:>3} of {:>3} steps (floor {min}), largest gap {:.1e} m",
                p.name, e.context, e.steps_within, e.steps_original, e.max_within_m
            );
            if e.steps_within < min {
                shorter.push(format!(
                    "{} initial state {}: {} steps, was {min}",
                    p.name, e.context, e.steps_within
                ));
            }
        }
    }
    assert!(
        shorter.is_empty(),
        "replays follow the original for fewer steps: {shorter:#?}"
    );
}
