//! Issue 41: evaluations take their initial states in a seeded random order
//! and report them as they complete, in that order, with results the same
//! bit for bit as before; `d3il compare --sequential --task T A B` races two
//! policies on the same states and stops when the paired test decides.

use d3il_evaluator::canary;
use d3il_evaluator::eval::race::{self, Contender, RaceOptions, RaceReport};
use d3il_evaluator::eval::{self, EvalOptions, PolicyInfo};
use d3il_evaluator::scripted::ScriptedPolicy;
use d3il_evaluator::tasks::LoadedTask;
use d3il_metrics::order::state_order;
use d3il_policy::{OnnxPolicy, Policy};
use d3il_protocol::{ObsType, PolicyManifest, Progress, ProtocolKind, TaskId};
use std::path::{Path, PathBuf};
use std::process::Command;

const EXE: &str = env!("CARGO_BIN_EXE_d3il");

fn assets() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("assets")
}

fn fixture(task: &LoadedTask, name: &str, seed: u64) -> (Box<dyn Policy>, PolicyInfo) {
    let dir = assets().join("fixtures");
    let bytes = std::fs::read(dir.join(format!("{name}.onnx"))).unwrap();
    let manifest: PolicyManifest =
        serde_json::from_slice(&std::fs::read(dir.join(format!("{name}.json"))).unwrap()).unwrap();
    let p = OnnxPolicy::load(&bytes, &manifest, &task.spec(), seed).unwrap();
    let info = PolicyInfo {
        sha256: eval::sha256_hex(&bytes),
        obs_type: ObsType::State,
    };
    (Box::new(p), info)
}

fn scripted(task: &LoadedTask, name: &str) -> (Box<dyn Policy>, PolicyInfo) {
    let p = ScriptedPolicy::from_name(name, task.spec()).unwrap();
    let info = PolicyInfo {
        sha256: eval::sha256_hex(name.as_bytes()),
        obs_type: ObsType::State,
    };
    (Box::new(p), info)
}

/// The committed drift canary was recorded with the states taken in index
/// order; under the random order every rollout's outcome (success,
/// behaviour, steps, ending, final poses, final physics digest) is the same
/// to the bit: a stochastic policy (noise input, two rollouts per state), a
/// scripted one, and an image policy run in one slot (so the order decides
/// which rollout follows which in it).
#[test]
fn a_randomly_ordered_evaluation_reproduces_the_committed_canary() {
    // The canary's evaluations (quick protocol: 3 states, seed 0) really
    // are reordered.
    assert_ne!(state_order(3, 0), vec![0, 1, 2]);
    let expected = canary::expected(&assets()).unwrap();
    let names = [
        "aligning/state/aligning_mlp_noise",
        "aligning/state/scripted:aligning:both",
        "aligning/image/aligning_image_k2_h4",
    ];
    for e in canary::ENTRIES
        .iter()
        .filter(|e| names.contains(&&*e.name()))
    {
        let got = canary::run_entry(e, &assets()).unwrap();
        let checks = canary::compare(
            &expected,
            &canary::Outcomes {
                entries: vec![got.clone()],
            },
        );
        assert_eq!(checks.len(), 1);
        let c = &checks[0];
        assert!(
            c.first_difference.is_none() && c.matching == c.rollouts && c.rollouts == 6,
            "{}: {c:?}",
            e.name()
        );
    }
}

/// Progress reports every initial state once, as a prefix of the seeded
/// order, with the outcomes the result records for it; the result does not
/// depend on how many rollouts run at once (the order of completion).
#[test]
fn progress_reports_the_states_in_the_seeded_order_with_their_outcomes() {
    let task = LoadedTask::load(TaskId::Aligning).unwrap();
    for (seed, max_live) in [(0u64, 1usize), (7, 3), (7, 96)] {
        let (mut policy, info) = fixture(&task, "aligning_mlp_noise", seed);
        let opts = EvalOptions {
            protocol: ProtocolKind::Quick,
            seed,
            max_live,
            step_cap: Some(60),
            bootstrap_resamples: 10,
            ..EvalOptions::default()
        };
        let mut reports: Vec<Progress> = vec![];
        let mut on_progress = |p: &Progress| reports.push(p.clone());
        let run = eval::EvalRun::all().reporting(&mut on_progress);
        let (result, _) = eval::evaluate(&task, policy.as_mut(), &info, &opts, run).unwrap();
        let states: Vec<_> = reports.iter().flat_map(|p| p.states.clone()).collect();
        let n = result.manifest.n_contexts;
        let per = result.manifest.rollouts_per_context;
        assert_eq!(per, 2, "the noise fixture runs every rollout");
        assert_eq!(
            states.iter().map(|s| s.context_index).collect::<Vec<_>>(),
            state_order(n, seed),
            "seed {seed}, max_live {max_live}"
        );
        assert_eq!(
            states.iter().map(|s| s.position).collect::<Vec<_>>(),
            (0..n).collect::<Vec<_>>()
        );
        for s in &states {
            let recorded: Vec<bool> = result
                .rollouts
                .iter()
                .filter(|r| r.context_index == s.context_index)
                .map(|r| r.success)
                .collect();
            assert_eq!(s.successes, recorded);
        }
        // Reported only when complete: the rollouts done cover them.
        for p in &reports {
            assert!(p.rollouts_done <= p.rollouts_total);
        }
        let last = reports.last().unwrap();
        assert_eq!(last.rollouts_done, n * per);
        // Records are stored by rollout id whatever the order.
        let ids: Vec<usize> = result
            .rollouts
            .iter()
            .map(|r| r.context_index * per + r.rollout_index)
            .collect();
        assert_eq!(ids, (0..n * per).collect::<Vec<_>>());
    }
}

/// A real race on Aligning (paper protocol, 60 initial states × 8
/// rollouts): the scripted expert against the untrained MLP fixture. It
/// decides "A better" after a handful of initial states, and what it used
/// agrees with full evaluations of both on those states.
#[test]
fn a_race_of_two_policies_decides_early() {
    let fixture_path = assets().join("fixtures/aligning_mlp.onnx");
    let out = Command::new(EXE)
        .args(["compare", "--sequential", "--task", "aligning", "--json"])
        .arg("scripted:aligning:inside")
        .arg(&fixture_path)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let r: RaceReport = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(r.decision.as_deref(), Some("A better"), "{r:?}");
    assert_eq!((r.states_full, r.rollouts_full), (60, 960));
    assert_eq!(r.pair, "initial state (its rollout 0)");
    assert!(r.states_used < 30, "decided early: {r:?}");
    assert_eq!(r.rollouts_used, 2 * 8 * r.states_used);
    assert_eq!(r.pairs_used, r.decided_at.unwrap());
    // Decided by the boundary calibrated to the 60 states: A's lead
    // reached it; the e-value (reported, anytime-valid) grew with it.
    let boundary = d3il_metrics::sequential::CalibratedBoundary::new(0.05, 60);
    let (w, l) = r.discordant;
    assert!(
        boundary
            .running_bound((w + l) as usize)
            .is_some_and(|b| w >= l + b),
        "{r:?}"
    );
    assert!(r.e_value > 1.0 && r.p_value < 1.0, "{r:?}");
    // A (a one-variant script) and B (an ONNX graph without noise) are
    // deterministic: at most one simulation per state each, fewer than the
    // rollouts the race used, and it stopped before every state ran.
    assert!(r.rollouts_simulated < r.rollouts_used, "{r:?}");
    assert!(r.rollouts_simulated < 2 * r.states_full, "{r:?}");
    // The untrained fixture never succeeds: every discordant pair is A's.
    assert_eq!(r.discordant.1, 0);
    assert!(r.fixed_pairs_for_power_90.is_some());

    // In process, the same race gives the same report but for the clock.
    let task = LoadedTask::load(TaskId::Aligning).unwrap();
    let (mut a, info_a) = scripted(&task, "aligning:inside");
    let (mut b, info_b) = fixture(&task, "aligning_mlp", 0);
    let (mut seen, mut wins_a, mut successes_a) = (0, 0, 0);
    let again = race::race(
        &task,
        Contender {
            policy: a.as_mut(),
            info: &info_a,
        },
        Contender {
            policy: b.as_mut(),
            info: &info_b,
        },
        &EvalOptions {
            max_live: 8,
            ..EvalOptions::default()
        },
        &RaceOptions::default(),
        &mut |p| {
            seen += 1;
            assert_eq!(p.a.context_index, p.b.context_index);
            assert_eq!(p.a.context_index, state_order(60, 0)[p.states - 1]);
            assert_eq!((p.a.successes.len(), p.b.successes.len()), (8, 8));
            wins_a += (p.a.successes[0] && !p.b.successes[0]) as u64;
            successes_a += p.a.successes.iter().filter(|s| **s).count();
        },
    )
    .unwrap();
    assert_eq!(seen, r.states_used);
    assert_eq!(wins_a, r.discordant.0);
    assert_eq!(r.rate_a, successes_a as f64 / (8 * r.states_used) as f64);
    assert_eq!(
        (again.decided_at, again.discordant, again.rollouts_used),
        (r.decided_at, r.discordant, r.rollouts_used)
    );
}

#[test]
fn a_race_refuses_a_bad_level_or_policy_with_what_to_fix() {
    let out = Command::new(EXE)
        .args([
            "compare",
            "--sequential",
            "--task",
            "aligning",
            "--alpha",
            "1.5",
            "scripted:aligning:inside",
            "scripted:aligning:outside",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("alpha 1.5 is not in (0, 1)"), "{err}");
    let out = Command::new(EXE)
        .args([
            "compare",
            "--sequential",
            "--task",
            "aligning",
            "scripted:aligning:inside",
            "no/such/policy.onnx",
        ])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("no/such/policy.onnx: no such file"), "{err}");
}
