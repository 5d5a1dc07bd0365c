//! Episode-start semantics of the lockstep engine with real MuJoCo: a policy
//! whose window grows (as the reference agents' deques do) sees windows of
//! 1, 2, …, k observations on its first k queries of every episode, one
//! batched call per window length, and its own previous outputs in
//! `prev_actions`.

use d3il_evaluator::eval::{evaluate, EvalOptions, EvalRun, PolicyInfo};
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::{ActionChunks, Policy, PolicyError, PolicyShape, Query, WindowMode};
use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use std::collections::HashMap;

const K: usize = 3;
const OBS: usize = 20;
const ACT: usize = 3;

/// What one row of one query carried.
#[derive(Debug, Clone)]
struct Seen {
    step: u64,
    window: usize,
    obs: Vec<f32>,
    prev: Vec<f32>,
    /// The action returned for it.
    out: Vec<f32>,
}

struct Recorder {
    mode: WindowMode,
    seen: HashMap<u64, Vec<Seen>>,
    /// Window lengths of each call (one call per length per lockstep iteration).
    calls: Vec<Vec<usize>>,
    iteration_windows: Vec<usize>,
}

impl Policy for Recorder {
    fn shape(&self) -> PolicyShape {
        PolicyShape {
            history: K,
            horizon: 1,
            execute: 1,
            obs_dim: OBS,
            act_dim: ACT,
            obs_type: ObsType::State,
        }
    }
    fn reset(&mut self, _ids: &[u64]) -> Result<(), PolicyError> {
        Ok(())
    }
    fn infer(&mut self, q: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        q.check(&self.shape())?;
        let w = q.window_len(K);
        if self.iteration_windows.last().is_some_and(|&l| l >= w) {
            self.calls.push(std::mem::take(&mut self.iteration_windows));
        }
        self.iteration_windows.push(w);
        let prev = q.prev_actions.expect("prev_actions given");
        let mut data = vec![];
        for (r, (&id, &step)) in q.rollout_ids.iter().zip(q.steps).enumerate() {
            // A small action that differs per rollout and step.
            let out = vec![
                0.0005 * ((step % 5) as f32 - 2.0),
                0.0003 * (id as f32 - 2.0),
                -0.0002 * (step % 3) as f32,
            ];
            self.seen.entry(id).or_default().push(Seen {
                step,
                window: w,
                obs: q.obs[r * w * OBS..(r + 1) * w * OBS].to_vec(),
                prev: prev[r * (w - 1) * ACT..(r + 1) * (w - 1) * ACT].to_vec(),
                out: out.clone(),
            });
            data.extend(out);
        }
        Ok(ActionChunks {
            batch: q.batch(),
            horizon: 1,
            act_dim: ACT,
            data,
        })
    }
    fn window(&self) -> WindowMode {
        self.mode
    }
    fn takes_prev_actions(&self) -> bool {
        true
    }
}

fn run(mode: WindowMode, max_live: usize) -> Recorder {
    let task = LoadedTask::load(TaskId::Aligning).unwrap();
    let mut p = Recorder {
        mode,
        seen: HashMap::new(),
        calls: vec![],
        iteration_windows: vec![],
    };
    let info = PolicyInfo {
        sha256: "recorder".into(),
        obs_type: ObsType::State,
    };
    let opts = EvalOptions {
        protocol: ProtocolKind::Quick,
        seed: 0,
        max_live,
        bootstrap_resamples: 10,
        ..EvalOptions::default()
    };
    let (r, _) = evaluate(&task, &mut p, &info, &opts, EvalRun::all()).unwrap();
    assert_eq!(r.rollouts.len(), 6);
    p
}

#[test]
fn growing_window_sees_1_to_k_and_its_own_previous_actions() {
    // 4 slots for 6 rollouts: two episodes start mid-run, so calls mix lengths.
    let p = run(WindowMode::Grow, 4);
    assert_eq!(p.seen.len(), 6);
    for (id, seen) in &p.seen {
        for (i, s) in seen.iter().enumerate() {
            assert_eq!(s.step, i as u64, "rollout {id}: one query per step");
            assert_eq!(s.window, (i + 1).min(K), "rollout {id}, query {i}");
            // The newest observation of a window is the previous window's newest
            // shifted by one: the window slides over the same episode.
            if i > 0 {
                let before = &seen[i - 1];
                let w = s.window;
                assert_eq!(
                    &s.obs[(w - 2) * OBS..(w - 1) * OBS],
                    &before.obs[(before.window - 1) * OBS..],
                    "rollout {id}, query {i}"
                );
            }
            // prev_actions: this rollout's own last w−1 outputs, oldest first.
            let want: Vec<f32> = seen[i + 1 - s.window..i]
                .iter()
                .flat_map(|x| x.out.clone())
                .collect();
            assert_eq!(s.prev, want, "rollout {id}, query {i}");
        }
    }
    // Rollouts that started later gave lockstep iterations with two lengths.
    assert!(
        p.calls.iter().any(|c| c.len() > 1),
        "no iteration grouped two window lengths"
    );
}

#[test]
fn padded_window_repeats_the_first_observation_and_zero_fills_prev_actions() {
    let p = run(WindowMode::Pad, 6);
    for (id, seen) in &p.seen {
        let first = &seen[0];
        assert_eq!(first.window, K);
        for j in 1..K {
            assert_eq!(
                &first.obs[j * OBS..(j + 1) * OBS],
                &first.obs[..OBS],
                "rollout {id}"
            );
        }
        assert!(first.prev.iter().all(|&x| x == 0.0), "rollout {id}");
        assert_eq!(first.prev.len(), (K - 1) * ACT);
        let second = &seen[1];
        assert_eq!(&second.prev[..ACT], &[0.0; ACT]);
        assert_eq!(&second.prev[ACT..], &first.out[..]);
    }
}
