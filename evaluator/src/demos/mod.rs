//! Demonstrations for training with the D3IL reference code (`d3il demos`):
//! the scripted experts recorded on training initial states, written as the
//! reference's dataset classes read them (per-episode pickles and the
//! train/eval file lists its task configs name).
//!
//! What a recorded step holds is exactly what the evaluator feeds a policy at
//! that step ([`Env::policy_obs`]: previous command, then the task's
//! observation) and the action the expert took, so a policy trained on these
//! files sees at evaluation what it saw in training. The reference's datasets
//! rebuild the action as `des_c_pos[t + 1] - des_c_pos[t]`; `des_c_pos` is the
//! evaluator's previous command in float64 ([`Env::prev_command`]), which is
//! the running sum of the actions, so the difference gives back the action.
//!
//! Variation inside a behaviour (so that a learner sees more than one path
//! per mode): each episode draws a speed factor that scales the expert's
//! actions, and adds smooth noise to them (an AR(1) process scaled by the
//! action's own size, so a resting expert stays at rest). The experts are
//! closed-loop, so they correct what the noise and speed change. An episode
//! that fails, or is longer than the reference's `max_len_data` allows, is
//! dropped and its behaviour is tried again on the next training state; so is
//! a success the task gives no behaviour label.

pub mod pickle;

use crate::robot::kinematics::PandaKinematics;
use crate::scripted::ScriptedPolicy;
use crate::tasks::{CommandKind, Env, LoadedTask, TaskError};
use d3il_protocol::TaskId;
use pickle::Py;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::Serialize;
use serde_json::Value;
use std::collections::BTreeMap;

/// Version of the demonstration generator's output (bump when the bytes for
/// the same seed change).
pub const DEMOS_VERSION: &str = "v1";

/// Knobs of one recording.
#[derive(Debug, Clone, Serialize)]
pub struct DemoOptions {
    /// Successful episodes to write.
    pub episodes: usize,
    pub seed: u64,
    /// Each episode's speed factor is uniform in this range.
    pub speed: (f64, f64),
    /// Standard deviation of the action noise, relative to the action's norm.
    pub noise: f64,
    /// Correlation of the noise from one step to the next (AR(1)).
    pub noise_correlation: f64,
    /// Fraction of the episodes listed in the eval file list (at least one).
    pub eval_fraction: f64,
    /// Tries per episode before giving up (each on a fresh training state).
    pub max_attempts: usize,
}

impl Default for DemoOptions {
    fn default() -> Self {
        DemoOptions {
            episodes: 100,
            seed: 0,
            speed: (0.85, 1.15),
            noise: 0.15,
            noise_correlation: 0.9,
            eval_fraction: 0.1,
            max_attempts: 20,
        }
    }
}

#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    #[error("{0}")]
    Task(#[from] TaskError),
    #[error("{0}")]
    Setup(String),
}

/// The reference's on-disk layout and key names for one task.
pub struct Layout {
    /// Directory of the per-episode files, relative to the task's data root
    /// (`environments/dataset/data/<root>/` in a reference checkout).
    pub root: &'static str,
    pub episode_dir: &'static str,
    /// File names of the train and eval lists (None: the dataset lists the
    /// episode directory itself, as Avoiding's does).
    pub lists: Option<(&'static str, &'static str)>,
    /// `max_len_data` of the task config: an episode of more steps than
    /// this does not fit the reference's padded arrays.
    pub max_len_data: usize,
    /// Objects after the robot: (name, where in the policy observation, how).
    pub objects: Vec<(String, ObsField)>,
    /// Entries the dataset reads but does not put into the observation.
    pub unused: Vec<(String, &'static str)>,
}

/// How an object's entries are rebuilt from the policy observation.
#[derive(Debug, Clone, Copy)]
pub enum ObsField {
    /// `pos` = obs[i..i+3], `quat` = obs[i+3..i+7] (wxyz).
    PosQuat(usize),
    /// `pos` = (obs[i], obs[i+1], 0), `quat` = the yaw rotation whose tangent
    /// is obs[i+2] (the reference reads `tan(quat2euler(quat)[-1])`).
    XyTanYaw(usize),
    /// `pos` = obs[i..i+3], `quat` = the yaw rotation whose tangent is
    /// obs[i+3] (Stacking's blocks: their height matters, their tilt is not
    /// observed).
    XyzTanYaw(usize),
}

/// The reference's layout for `task` (docs/zoo.md; read from
/// ALRhub/d3il's `environments/dataset/*_dataset.py` and `configs/*`).
pub fn layout(task: TaskId) -> Result<Layout, DemoError> {
    let c = crate::tasks::task_def(task)?.cmd_dim();
    let boxes = |names: &[&str]| -> Vec<(String, ObsField)> {
        names
            .iter()
            .enumerate()
            .map(|(k, n)| (n.to_string(), ObsField::XyTanYaw(2 * c + 3 * k)))
            .collect()
    };
    let sorting = |n: usize, root: &'static str, dir: &'static str, lists, len| {
        let mut names: Vec<String> = (1..=n / 2).map(|i| format!("red-box{i}")).collect();
        names.extend((1..=n / 2).map(|i| format!("blue-box{i}")));
        let refs: Vec<&str> = names.iter().map(String::as_str).collect();
        Layout {
            root,
            episode_dir: dir,
            lists: Some(lists),
            max_len_data: len,
            objects: boxes(&refs),
            unused: vec![],
        }
    };
    Ok(match task {
        TaskId::Avoiding => Layout {
            root: "avoiding",
            episode_dir: "data",
            lists: None,
            max_len_data: 200,
            objects: vec![],
            unused: vec![],
        },
        TaskId::Aligning => Layout {
            root: "aligning",
            episode_dir: "all_data/state",
            lists: Some(("train_files.pkl", "eval_files.pkl")),
            max_len_data: 512,
            objects: vec![
                ("push-box".into(), ObsField::PosQuat(2 * c)),
                ("target-box".into(), ObsField::PosQuat(2 * c + 7)),
            ],
            unused: vec![],
        },
        TaskId::Pushing => Layout {
            root: "pushing",
            episode_dir: "all_data",
            lists: Some(("train_files.pkl", "eval_files.pkl")),
            max_len_data: 512,
            objects: boxes(&["red-box", "green-box"]),
            unused: vec![("red-target".into(), "pos"), ("green-target".into(), "pos")],
        },
        TaskId::Sorting2 => sorting(
            2,
            "sorting",
            "2_boxes/state",
            ("2_boxes_train_files.pkl", "2_boxes_eval_files.pkl"),
            600,
        ),
        TaskId::Sorting4 => sorting(
            4,
            "sorting",
            "4_boxes/state",
            ("4_boxes_train_files.pkl", "4_boxes_eval_files.pkl"),
            600,
        ),
        TaskId::Sorting6 => sorting(
            6,
            "sorting",
            "6_boxes/state",
            ("6_boxes_train_files.pkl", "6_boxes_eval_files.pkl"),
            1200,
        ),
        // The observation is the previous joint command and gripper width
        // (8, see `episode_pickle`), then x, y, z and tan(yaw) of each block.
        TaskId::Stacking => Layout {
            root: "stacking",
            episode_dir: "all_data",
            lists: Some(("train_files.pkl", "eval_files.pkl")),
            max_len_data: 1000,
            objects: ["red-box", "green-box", "blue-box"]
                .iter()
                .enumerate()
                .map(|(k, n)| (n.to_string(), ObsField::XyzTanYaw(c + 4 * k)))
                .collect(),
            unused: vec![],
        },
        TaskId::Inserting => {
            return Err(DemoError::Setup(
                "d3il demos does not write inserting: the reference code has no dataset class \
                 or task config for it (environments/dataset, configs), so there is no format \
                 its training reads; the state tasks it writes are avoiding, aligning, pushing, \
                 sorting-2, sorting-4, sorting-6, stacking"
                    .into(),
            ))
        }
    })
}

/// The expert whose variants cover every behaviour the task counts.
pub fn expert_name(task: TaskId) -> Result<&'static str, DemoError> {
    Ok(match task {
        TaskId::Avoiding => "avoiding:all-paths",
        TaskId::Aligning => "aligning:both",
        TaskId::Pushing => "pushing:all-modes",
        TaskId::Sorting2 => "sorting-2:all-orders",
        TaskId::Sorting4 => "sorting-4:all-orders",
        TaskId::Sorting6 => "sorting-6:all-orders",
        TaskId::Stacking => "stacking:all-orders",
        TaskId::Inserting => {
            return Err(DemoError::Setup(
                "inserting has no scripted expert that covers its behaviours".into(),
            ))
        }
    })
}

/// One recorded, successful episode.
pub struct Episode {
    pub index: usize,
    /// Which try of the episode this was (0: the first).
    pub attempt: usize,
    pub variant: usize,
    pub behaviour: String,
    pub steps: usize,
    pub speed: f64,
    pub context: Value,
    /// Previous command at steps 0..=T (float64, cmd_dim each).
    pub des: Vec<f64>,
    /// Policy observation at steps 0..=T (float32, obs_dim each).
    pub obs: Vec<f32>,
    /// Joint-space tasks only (empty otherwise): the measured arm at steps
    /// 0..=T, [`MEASURED`] values each (joints, joint velocities, TCP
    /// position and quaternion), which the reference's Stacking dataset
    /// reads but does not put into its observation.
    pub measured: Vec<f64>,
    pub fixed_z: f64,
}

/// Width of one row of [`Episode::measured`]: j_pos 7, j_vel 7, c_pos 3, c_quat 4.
pub const MEASURED: usize = 21;

fn measure(env: &Env, out: &mut Vec<f64>) {
    out.extend(env.sim.joint_pos());
    out.extend(env.sim.joint_vel());
    out.extend(env.sim.tcp_pos());
    out.extend(env.sim.tcp_quat());
}

/// Tries made and why they were dropped.
#[derive(Debug, Default, Clone, Serialize)]
pub struct Attempts {
    pub tried: usize,
    pub failed: usize,
    pub too_long: usize,
    /// Successes the task gives no behaviour label (e.g. a Pushing run that
    /// pushed a box into the wrong target first): not a demonstration of a mode.
    pub unlabeled: usize,
}

impl Attempts {
    fn add(&mut self, o: &Attempts) {
        self.tried += o.tried;
        self.failed += o.failed;
        self.too_long += o.too_long;
        self.unlabeled += o.unlabeled;
    }
}

/// A training initial state: drawn from the task's distribution with a seed
/// of its own per (seed, episode, attempt), so that every episode is the same
/// computation whatever the thread count.
fn training_context(task: &LoadedTask, seed: u64, index: usize, attempt: usize) -> Value {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(((index as u64) << 16) | attempt as u64);
    task.def.sample_context(&mut rng)
}

fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    // Box–Muller; u1 in (0, 1] so the log is finite.
    let u1: f64 = 1.0 - rng.gen::<f64>();
    let u2: f64 = rng.gen();
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Runs one try of episode `index`; `None` when it failed or ran too long.
fn try_episode(
    task: &LoadedTask,
    expert: &str,
    opts: &DemoOptions,
    max_len: usize,
    index: usize,
    attempt: usize,
    test_set: &[Value],
) -> Result<(Option<Episode>, Attempts), DemoError> {
    // A policy of its own per try: its live-rollout map is not shareable
    // between threads, and making one costs nothing next to an episode.
    let expert = ScriptedPolicy::from_name(expert, task.def.spec())
        .map_err(|e| DemoError::Setup(e.to_string()))?;
    let variant = index % expert.variants();
    let context = training_context(task, opts.seed, index, attempt);
    if !context.is_null() && test_set.contains(&context) {
        return Ok((None, Attempts::default()));
    }
    let mut rng = ChaCha8Rng::seed_from_u64(opts.seed ^ 0x5eed_de30);
    rng.set_stream(((index as u64) << 16) | attempt as u64);
    let speed = rng.gen_range(opts.speed.0..=opts.speed.1);
    let mut env = Env::new(task)?;
    env.reset(&context)?;
    let mut script = expert.script(variant);
    let kind = task.def.command_kind();
    let joint = kind == CommandKind::JointDelta;
    // Speed and noise change the increments only: an absolute entry
    // (Stacking's gripper width) scaled or jittered is another command.
    let increments = kind.increments();
    let mut noise = vec![0.0f64; increments];
    let rho = opts.noise_correlation;
    let innovation = (1.0 - rho * rho).sqrt();
    let (mut des, mut obs, mut measured) = (Vec::new(), Vec::new(), Vec::new());
    let mut steps = 0;
    while !env.is_done() {
        let o = env.policy_obs();
        des.extend_from_slice(env.prev_command());
        obs.extend_from_slice(&o);
        if joint {
            measure(&env, &mut measured);
        }
        let mut action = script.act(&o);
        let norm = action[..increments]
            .iter()
            .map(|&v| (v as f64).powi(2))
            .sum::<f64>()
            .sqrt();
        for (v, n) in action.iter_mut().zip(noise.iter_mut()) {
            *n = rho * *n + innovation * standard_normal(&mut rng);
            *v = (*v as f64 * speed + opts.noise * norm * *n) as f32;
        }
        env.step(&action)?;
        steps += 1;
    }
    let tried = Attempts {
        tried: 1,
        ..Attempts::default()
    };
    if !env.success() {
        return Ok((None, Attempts { failed: 1, ..tried }));
    }
    let Some(behaviour) = env.behaviour_key() else {
        return Ok((
            None,
            Attempts {
                unlabeled: 1,
                ..tried
            },
        ));
    };
    if steps >= max_len {
        return Ok((
            None,
            Attempts {
                too_long: 1,
                ..tried
            },
        ));
    }
    des.extend_from_slice(env.prev_command());
    obs.extend_from_slice(&env.policy_obs());
    if joint {
        measure(&env, &mut measured);
    }
    Ok((
        Some(Episode {
            index,
            attempt,
            variant,
            behaviour,
            steps,
            speed,
            context,
            des,
            obs,
            measured,
            fixed_z: env.fixed_z(),
        }),
        tried,
    ))
}

/// Records `opts.episodes` successful episodes of the task's expert, in
/// parallel, the same bytes for the same seed whatever the thread count.
pub fn record(
    task: &LoadedTask,
    opts: &DemoOptions,
) -> Result<(Vec<Episode>, Attempts), DemoError> {
    let id = task.def.id();
    let expert = expert_name(id)?;
    let max_len = layout(id)?.max_len_data;
    let test_set = task.def.context_set()?.file.contexts;
    let results: Vec<Result<(Option<Episode>, Attempts), DemoError>> = (0..opts.episodes)
        .into_par_iter()
        .map(|index| {
            let mut total = Attempts::default();
            for attempt in 0..opts.max_attempts {
                let (ep, a) = try_episode(task, expert, opts, max_len, index, attempt, &test_set)?;
                total.add(&a);
                if ep.is_some() {
                    return Ok((ep, total));
                }
            }
            Ok((None, total))
        })
        .collect();
    let mut episodes = Vec::new();
    let mut total = Attempts::default();
    for (index, r) in results.into_iter().enumerate() {
        let (ep, a) = r?;
        total.add(&a);
        match ep {
            Some(e) => episodes.push(e),
            None => return Err(gave_up(id, opts, max_len, index, &a)),
        }
    }
    Ok((episodes, total))
}

/// The error of an episode none of whose tries made a demonstration: what
/// went wrong, and the option that addresses it.
fn gave_up(
    id: TaskId,
    opts: &DemoOptions,
    max_len: usize,
    index: usize,
    a: &Attempts,
) -> DemoError {
    let hint = if a.too_long * 2 >= a.tried {
        format!(
            "most ran longer than the reference config's max_len_data of {max_len} steps: \
             raise --speed (the expert's pace; now {:.2}..{:.2})",
            opts.speed.0, opts.speed.1
        )
    } else {
        "lower --noise or narrow --speed-spread".to_string()
    };
    DemoError::Setup(format!(
        "the {id} expert did not make episode {index} in {} tries ({} failed, {} longer than \
         {max_len} steps, {} without a behaviour label); {hint}; nothing was written",
        a.tried, a.failed, a.too_long, a.unlabeled
    ))
}

/// The per-episode pickle: `{"robot": {"des_c_pos", "c_pos"}, <object>: {"pos", "quat"}, ...}`
/// as the reference's dataset class reads it (Stacking's robot: the joint-space
/// entries of [`joint_robot`]).
pub fn episode_pickle(task: TaskId, ep: &Episode) -> Result<Vec<u8>, DemoError> {
    let lay = layout(task)?;
    let joint = crate::tasks::task_def(task)?.command_kind() == CommandKind::JointDelta;
    let rows = ep.steps + 1;
    let c = ep.des.len() / rows;
    let obs_dim = ep.obs.len() / rows;
    let o = |t: usize, i: usize| ep.obs[t * obs_dim + i] as f64;
    let array = move |cols: usize, f: &dyn Fn(usize, usize) -> f64| Py::Array {
        shape: vec![rows, cols],
        data: (0..rows)
            .flat_map(|t| (0..cols).map(move |j| (t, j)))
            .map(|(t, j)| f(t, j))
            .collect(),
    };
    let robot = if joint {
        joint_robot(ep, rows, &array)
    } else {
        // The desired TCP is the previous command (float64); the measured
        // TCP is the observation's. Tasks whose command is planar get the
        // frozen height as z (the reference reads [:, :2] there).
        let des = array(3, &|t, j| {
            if j < c {
                ep.des[t * c + j]
            } else {
                ep.fixed_z
            }
        });
        let cpos = array(3, &|t, j| if j < c { o(t, c + j) } else { ep.fixed_z });
        vec![("des_c_pos".into(), des), ("c_pos".into(), cpos)]
    };
    let mut entries = vec![("robot".to_string(), Py::Dict(robot))];
    for (name, field) in &lay.objects {
        let (pos, quat) = match *field {
            ObsField::PosQuat(i) => (
                array(3, &|t, j| o(t, i + j)),
                array(4, &|t, j| o(t, i + 3 + j)),
            ),
            ObsField::XyTanYaw(i) => (
                array(3, &|t, j| if j < 2 { o(t, i + j) } else { 0.0 }),
                array(4, &|t, j| yaw_quat(o(t, i + 2), j)),
            ),
            ObsField::XyzTanYaw(i) => (
                array(3, &|t, j| o(t, i + j)),
                array(4, &|t, j| yaw_quat(o(t, i + 3), j)),
            ),
        };
        entries.push((
            name.clone(),
            Py::Dict(vec![("pos".into(), pos), ("quat".into(), quat)]),
        ));
    }
    for (name, key) in &lay.unused {
        entries.push((
            name.clone(),
            Py::Dict(vec![((*key).into(), array(3, &|_, _| 0.0))]),
        ));
    }
    Ok(pickle::dumps(&Py::Dict(entries)))
}

/// Entry `j` (w, x, y, z) of the yaw-only quaternion whose yaw has tangent
/// `tan_yaw`: the reference reads `tan(quat2euler(quat)[-1])` back.
fn yaw_quat(tan_yaw: f64, j: usize) -> f64 {
    let half = tan_yaw.atan() / 2.0;
    match j {
        0 => half.cos(),
        3 => half.sin(),
        _ => 0.0,
    }
}

/// Builds a `[rows, cols]` array from `f(row, col)`.
type ArrayOf = dyn Fn(usize, &dyn Fn(usize, usize) -> f64) -> Py;

/// Stacking's robot entries (ALRhub/d3il `Stacking_Dataset`): it builds the
/// observation from `des_j_pos` and `gripper_width` and the action from
/// `des_j_pos[t + 1] − des_j_pos[t]` and `gripper_width[t + 1]`; the others it
/// reads and leaves out. `des_j_pos` and `gripper_width` are therefore the
/// evaluator's previous command (the 7 desired joints, float32 sums, and the
/// gripper width the policy last asked for, docs/original-d3il.md §11.2.3),
/// so that the policy sees at evaluation what it saw in training;
/// `gripper_width` is one-dimensional, as the dataset expands it. `j_pos`,
/// `j_vel`, `c_pos` and `c_quat` are measured at the row's step;
/// `des_c_pos` and `des_c_quat` are the forward kinematics of `des_j_pos`; the
/// joint command carries no desired velocity, so `des_j_vel` is zeros.
fn joint_robot(ep: &Episode, rows: usize, array: &ArrayOf) -> Vec<(String, Py)> {
    let c = ep.des.len() / rows;
    let q = |t: usize| -> [f64; 7] { std::array::from_fn(|j| ep.des[t * c + j]) };
    let kin = PandaKinematics::new();
    let fk: Vec<_> = (0..rows)
        .map(|t| {
            let fk = kin.fk(&q(t));
            (fk.pos, fk.quat_wxyz())
        })
        .collect();
    let m = |t: usize, j: usize| ep.measured[t * MEASURED + j];
    vec![
        ("des_j_pos".into(), array(7, &|t, j| q(t)[j])),
        ("des_j_vel".into(), array(7, &|_, _| 0.0)),
        ("des_c_pos".into(), array(3, &|t, j| fk[t].0[j])),
        ("des_c_quat".into(), array(4, &|t, j| fk[t].1[j])),
        ("c_pos".into(), array(3, &|t, j| m(t, 14 + j))),
        ("c_quat".into(), array(4, &|t, j| m(t, 17 + j))),
        ("j_pos".into(), array(7, &|t, j| m(t, j))),
        ("j_vel".into(), array(7, &|t, j| m(t, 7 + j))),
        (
            "gripper_width".into(),
            Py::Array {
                shape: vec![rows],
                data: (0..rows).map(|t| ep.des[t * c + 7]).collect(),
            },
        ),
    ]
}

/// Behaviour histogram of the episodes (label -> count), labels sorted.
pub fn histogram(episodes: &[Episode]) -> BTreeMap<String, usize> {
    let mut h = BTreeMap::new();
    for e in episodes {
        *h.entry(e.behaviour.clone()).or_insert(0) += 1;
    }
    h
}

/// A pickled list of file names, as the reference's `np.load(..., allow_pickle=True)` reads it.
pub fn file_list_pickle(names: &[String]) -> Vec<u8> {
    pickle::dumps(&Py::List(names.iter().cloned().map(Py::Str).collect()))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An episode whose tries all failed names how they failed, and the
    /// option that addresses it: the pace when most ran too long (Sorting-4
    /// at its own pace), the noise otherwise.
    #[test]
    fn giving_up_says_how_the_tries_failed_and_what_to_change() {
        let opts = DemoOptions::default();
        let long = Attempts {
            tried: 20,
            failed: 3,
            too_long: 17,
            unlabeled: 0,
        };
        let e = gave_up(TaskId::Sorting4, &opts, 600, 5, &long).to_string();
        assert!(
            e.contains("episode 5 in 20 tries (3 failed, 17 longer than 600 steps")
                && e.contains("raise --speed (the expert's pace; now 0.85..1.15)")
                && e.contains("nothing was written"),
            "{e}"
        );
        let failing = Attempts {
            failed: 17,
            too_long: 3,
            ..long
        };
        let e = gave_up(TaskId::Sorting4, &opts, 600, 5, &failing).to_string();
        assert!(
            e.contains("lower --noise or narrow --speed-spread") && !e.contains("raise --speed"),
            "{e}"
        );
    }
}
