//! Latency in the engine (part of tests/robustness.rs): the environment
//! receives the actions the policy issued the set number of steps earlier,
//! whole steps on every convention, and on Stacking a fractional step that
//! blends the joint increments and takes the gripper value whole.

use super::*;

/// Latency: the environment receives the action the policy issued L steps
/// earlier, and the hold action before the first one arrives (a zero delta;
/// on Stacking zero joint deltas and an open gripper, as the reset left
/// it), for L = 1, 2, 4.
#[test]
fn a_scripted_expert_under_latency_acts_late_by_exactly_the_set_steps() {
    for (id, name, cap) in [
        (TaskId::Aligning, "aligning:inside", None),
        (TaskId::Pushing, "pushing:mode=1", None),
        (TaskId::Stacking, "stacking:order=r", Some(20)),
    ] {
        let task = LoadedTask::load(id).unwrap();
        for latency in [1usize, 2, 4] {
            let log: Log = Default::default();
            let mut policy = Recorder {
                inner: scripted(&task, name),
                log: log.clone(),
            };
            let p = perturbation(
                id,
                Axis::Latency,
                LevelSetting {
                    steps: Some(latency),
                    ..Default::default()
                },
            );
            let (r, _) = evaluate(
                &task,
                &mut policy,
                &info(),
                &capped(cap),
                EvalRun::all().perturbed(&p),
            )
            .unwrap();
            let hold = Active::new(&p, id).unwrap().hold;
            let log = log.lock().unwrap();
            for record in &r.rollouts {
                let id_ = (record.context_index * r.manifest.rollouts_per_context
                    + record.rollout_index) as u64;
                let applied = r.trace_of(record).unwrap().unpack().unwrap().actions;
                assert!(applied.len() > latency + 10);
                for (t, a) in applied.iter().enumerate() {
                    let expected = if t < latency {
                        hold.clone()
                    } else {
                        log[&(id_, (t - latency) as u64)].1.clone()
                    };
                    assert_eq!(
                        a, &expected,
                        "{id} latency {latency}, rollout {id_}, step {t}"
                    );
                }
            }
        }
    }
}

/// Wraps a Stacking policy and makes its gripper value alternate, open
/// (0.08) at even steps and closed (0) at odd ones, so that which late
/// action a gripper value came from shows in what the environment received.
struct BlinkingGripper<P>(P);

impl<P: Policy> Policy for BlinkingGripper<P> {
    fn shape(&self) -> PolicyShape {
        self.0.shape()
    }
    fn reset(&mut self, ids: &[u64]) -> Result<(), PolicyError> {
        self.0.reset(ids)
    }
    fn infer(&mut self, q: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        let mut out = self.0.infer(q)?;
        let per_row = out.horizon * out.act_dim;
        for (r, &step) in q.steps.iter().enumerate() {
            for h in 0..out.horizon {
                let open = (step as usize + h).is_multiple_of(2);
                out.data[r * per_row + h * out.act_dim + 7] = if open { 0.08 } else { 0.0 };
            }
        }
        Ok(out)
    }
}

/// A fractional latency L = n + f on Stacking (stacking-v2): the
/// environment receives the blend `(1 − f)·a(t − n) + f·a(t − n − 1)` of
/// the 7 joint increments and the absolute gripper value whole from the
/// action with the larger share, the older on a tie (`f` = 0.5); before an
/// action has arrived the hold action (zero increments, open gripper)
/// stands in for it. The gripper blinks (`BlinkingGripper`), so a blended
/// or a wrongly picked gripper value shows.
#[test]
fn stacking_under_a_fractional_latency_blends_the_joints_and_keeps_the_gripper_whole() {
    let id = TaskId::Stacking;
    let task = LoadedTask::load(id).unwrap();
    for (steps, fraction) in [(0usize, 0.25f64), (0, 0.5), (1, 0.9)] {
        let log: Log = Default::default();
        let mut policy = Recorder {
            inner: BlinkingGripper(scripted(&task, "stacking:order=r")),
            log: log.clone(),
        };
        let p = perturbation(
            id,
            Axis::Latency,
            LevelSetting {
                steps: Some(steps),
                fraction: Some(fraction),
                ..Default::default()
            },
        );
        let (r, _) = evaluate(
            &task,
            &mut policy,
            &info(),
            &capped(Some(16)),
            EvalRun::all().perturbed(&p),
        )
        .unwrap();
        let hold = Active::new(&p, id).unwrap().hold;
        assert!(hold[..7].iter().all(|&v| v == 0.0) && hold[7] > 0.075);
        let log = log.lock().unwrap();
        let f = fraction as f32;
        for record in &r.rollouts {
            let rollout = (record.context_index * r.manifest.rollouts_per_context
                + record.rollout_index) as u64;
            // What the policy issued `k` steps before step `t`.
            let issued = |t: usize, k: usize| match t.checked_sub(k) {
                Some(s) => log[&(rollout, s as u64)].1.clone(),
                None => hold.clone(),
            };
            let applied = r.trace_of(record).unwrap().unpack().unwrap().actions;
            assert_eq!(applied.len(), 16);
            let mut grippers = std::collections::BTreeSet::new();
            for (t, a) in applied.iter().enumerate() {
                let (newer, older) = (issued(t, steps), issued(t, steps + 1));
                let joints: Vec<f32> = (0..7)
                    .map(|j| (1.0 - f) * newer[j] + f * older[j])
                    .collect();
                let gripper = if f < 0.5 { newer[7] } else { older[7] };
                let at = format!("latency {steps} + {fraction}, rollout {rollout}, step {t}");
                assert_eq!(a[..7], joints[..], "{at}: joint increments");
                assert_eq!(a[7], gripper, "{at}: gripper");
                grippers.insert(a[7].to_bits());
            }
            assert_eq!(grippers.len(), 2, "the gripper did not blink");
        }
    }
}

/// Stacking's v1 suite (whole steps only) stays loadable after v2: a result
/// of its top latency level (4 steps) holds the hold action for the first 4
/// steps and then what the policy issued 4 steps earlier, and its rollouts
/// replay bit for bit against v1 (the manifest names v1 and its sha256).
#[test]
fn stacking_v1_latency_results_still_run_and_replay() {
    let id = TaskId::Stacking;
    let task = LoadedTask::load(id).unwrap();
    let v1 = Suite::named(id, "stacking-v1.json").unwrap();
    assert_ne!(
        Suite::for_task(id).unwrap().name,
        v1.name,
        "v1 is not current"
    );
    let p = v1
        .perturbations()
        .into_iter()
        .rev()
        .find(|p| p.axis == Axis::Latency)
        .unwrap();
    assert_eq!((p.setting.steps, p.setting.fraction), (Some(4), None));
    let log: Log = Default::default();
    let mut policy = Recorder {
        inner: scripted(&task, "stacking:order=g"),
        log: log.clone(),
    };
    let (r, _) = evaluate(
        &task,
        &mut policy,
        &info(),
        &capped(Some(12)),
        EvalRun::all().perturbed(&p),
    )
    .unwrap();
    assert_eq!(r.manifest.perturbation.as_ref(), Some(&p));
    let hold = Active::new(&p, id).unwrap().hold;
    let log = log.lock().unwrap();
    let replay_task = load_task(&r.manifest).unwrap();
    for record in &r.rollouts {
        let rollout =
            (record.context_index * r.manifest.rollouts_per_context + record.rollout_index) as u64;
        let trace = r.trace_of(record).unwrap();
        for (t, a) in trace.unpack().unwrap().actions.iter().enumerate() {
            let expected = match t.checked_sub(4) {
                Some(s) => &log[&(rollout, s as u64)].1,
                None => &hold,
            };
            assert_eq!(a, expected, "rollout {rollout}, step {t}");
        }
        let check = replay(&replay_task, &r.manifest, record, trace, &mut |_| Ok(())).unwrap();
        assert!(
            check.replays(),
            "rollout {rollout}: {:?}",
            check.differences
        );
    }
}
