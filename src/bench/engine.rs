//! The in-process benchmarks of `d3il bench`: controlled stepping against raw
//! `mj_step` (physics), a protocol's evaluation batched and row by row (eval),
//! the cameras and an image evaluation (render), and every agent fixture at
//! the evaluator's batch (agents).

use super::fixtures::load_fixture;
use anyhow::{bail, Context};
use d3il_evaluator::camera;
use d3il_evaluator::eval::{self, EvalOptions};
use d3il_evaluator::tasks::avoiding::AvoidingScript;
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::{ActionChunks, OnnxPolicy, Policy, PolicyError, PolicyShape, Query};
use d3il_protocol::{ObsType, PolicyManifest, ProtocolKind, TaskId};
use serde_json::Value;
use std::time::Instant;

/// Runs a policy one row at a time: the "unbatched" evaluation, with a model
/// exported for a fixed batch of 1.
struct RowByRow(OnnxPolicy);

impl Policy for RowByRow {
    fn shape(&self) -> PolicyShape {
        self.0.shape()
    }
    fn reset(&mut self, ids: &[u64]) -> Result<(), PolicyError> {
        self.0.reset(ids)
    }
    fn infer(&mut self, q: &Query<'_>) -> Result<ActionChunks, PolicyError> {
        let s = self.0.shape();
        let w = s.history * s.obs_dim;
        let mut out = ActionChunks {
            batch: q.batch(),
            horizon: s.horizon,
            act_dim: s.act_dim,
            data: Vec::with_capacity(q.batch() * s.horizon * s.act_dim),
        };
        for r in 0..q.batch() {
            let row = Query::new(
                &q.rollout_ids[r..r + 1],
                &q.steps[r..r + 1],
                &q.obs[r * w..(r + 1) * w],
            );
            out.data.extend_from_slice(&self.0.infer(&row)?.data);
        }
        Ok(out)
    }
}

/// `--smoke` ends every rollout of the eval and render benches' evaluations
/// after this many env steps (the dry run's step cap): the engine, the
/// policy calls and the timing all run, at a fraction of a full episode
/// (whole quick-protocol evaluations made these two smoke runs most of
/// tests/bench_smoke.rs's time).
pub(super) const SMOKE_EVAL_STEPS: usize = 60;

/// The full Aligning protocol with a BC-MLP-sized ONNX policy (20 -> 6 x 128
/// -> 3), batched (one call per lockstep step) and unbatched (one call per
/// rollout and step). Physics time is the wall time of the parallel stepping
/// phases of the same run.
pub(super) fn eval_bench(
    protocol: ProtocolKind,
    max_live: usize,
    step_cap: Option<usize>,
) -> anyhow::Result<()> {
    let task = LoadedTask::load(TaskId::Aligning)?;
    let threads = rayon::current_num_threads();
    println!(
        "aligning, protocol {protocol:?}, BC-MLP-sized ONNX policy (6 x 128), {max_live} live rollouts, {threads} threads"
    );
    // Every rollout, as a stochastic policy needs: this is what the physics
    // floor below is the floor of. (The fixture is deterministic; the last
    // run shows what simulating each initial state once saves it.)
    let opts = EvalOptions {
        protocol,
        seed: 0,
        max_live,
        simulate_every_rollout: true,
        step_cap,
        ..EvalOptions::default()
    };
    let mut ratios = Vec::new();
    let mut batched_s = 0.0;
    let mut total_env_steps = 0;
    for (label, name) in [
        ("batched", "aligning_mlp"),
        ("unbatched", "aligning_mlp_batch1"),
    ] {
        let (policy, info) = load_fixture(&task, name, ObsType::State)?;
        let mut policy: Box<dyn Policy> = if label == "batched" {
            Box::new(policy)
        } else {
            Box::new(RowByRow(policy))
        };
        let (r, t) = eval::evaluate(&task, policy.as_mut(), &info, &opts, eval::EvalRun::all())?;
        let n = r.rollouts.len();
        let steps: usize = r.rollouts.iter().map(|x| x.steps).sum();
        let other = t.total_s - t.physics_s - t.policy_s;
        println!(
            "{label:>9}: {n} rollouts ({steps} env steps) in {:.1} s = {:.2} rollouts/s; \
             physics {:.1} s, policy {:.2} s over {} calls ({:.3} ms/call, {:.1}% of physics), engine {:.2} s",
            t.total_s,
            n as f64 / t.total_s,
            t.physics_s,
            t.policy_s,
            t.policy_calls,
            1000.0 * t.policy_s / t.policy_calls.max(1) as f64,
            100.0 * t.policy_s / t.physics_s,
            other
        );
        ratios.push((label, t.total_s / t.physics_s));
        total_env_steps = steps;
        if label == "batched" {
            batched_s = t.total_s;
        }
    }
    let (mut policy, info) = load_fixture(&task, "aligning_mlp", ObsType::State)?;
    let once = EvalOptions {
        simulate_every_rollout: false,
        ..opts.clone()
    };
    let (_, t) = eval::evaluate(&task, &mut policy, &info, &once, eval::EvalRun::all())?;
    println!(
        "deterministic policy (no noise input), each initial state simulated once: {} of {} rollouts simulated, \
         {:.1} s ({:.1}x faster than batched, same results)",
        t.rollouts_simulated,
        t.rollouts,
        t.total_s,
        batched_s / t.total_s
    );
    // What the physics alone costs: the same number of raw mj_step calls on
    // this scene, spread over all threads, with no controller and no policy.
    let mj_steps = total_env_steps * task.def.n_substeps();
    let raw_rate = raw_step_rate(&task, threads)?;
    println!(
        "floor: {mj_steps} mj_step calls; raw mj_step on this scene runs {raw_rate:.0}/s on {threads} threads, \
         so no faithful evaluation of these rollouts can take less than {:.1} s here",
        mj_steps as f64 / raw_rate
    );
    println!(
        "ratio total/physics-only time: batched {:.3}, unbatched {:.3} (goal: policy < 10% of physics, i.e. batched <= 1.10)",
        ratios[0].1, ratios[1].1
    );
    Ok(())
}

/// Raw `mj_step` calls per second on the task's scene, one environment per
/// thread: segments of 500 steps holding the controls of a fresh reset (the
/// resets are not timed), two seconds of stepping per thread.
fn raw_step_rate(task: &LoadedTask, threads: usize) -> anyhow::Result<f64> {
    use rayon::prelude::*;
    let set = task.def.context_set()?;
    let rates: Vec<anyhow::Result<f64>> = (0..threads)
        .into_par_iter()
        .map(|i| {
            let mut env = task.env()?;
            let (mut n, mut secs) = (0usize, 0.0);
            let mut ctx = i;
            while secs < 2.0 {
                env.reset(&set.get(ctx % set.len()).cloned().unwrap_or(Value::Null))?;
                ctx += threads;
                let start = Instant::now();
                for _ in 0..500 {
                    env.sim.data.step()?;
                }
                secs += start.elapsed().as_secs_f64();
                n += 500;
            }
            Ok(n as f64 / secs)
        })
        .collect();
    let mut total = 0.0;
    for r in rates {
        total += r?;
    }
    Ok(total)
}

/// Frames per second of both 96 x 96 policy cameras; physics, rendering and
/// policy time per env step of an image-based Aligning evaluation run by the
/// engine (both cameras rendered every env step, as the image variant does;
/// times summed over threads); the paper-sized image policy (ResNet-18 per
/// camera, `aligning_resnet18` fixture) timed at the engine's batch of the
/// quick and the paper protocol and at batch 480; last line: the ratio of
/// rendering to physics time.
pub(super) fn render_bench(
    env_steps: usize,
    protocol: ProtocolKind,
    max_live: usize,
    look: crate::common::flags::Look,
    smoke: bool,
) -> anyhow::Result<()> {
    let look = look.robot_look();
    let task = LoadedTask::load_look(TaskId::Aligning, ObsType::Image, look)?;
    let set = task.def.context_set()?;
    let cams = camera::camera_ids(&task.model)?;
    println!(
        "aligning, cameras {} + {} at {}x{}, {look:?} robot, EGL: {}",
        camera::CAMERAS[0],
        camera::CAMERAS[1],
        camera::SIZE,
        camera::SIZE,
        d3il_evaluator::mujoco::egl_vendor()?
    );
    // Rendering alone: both cameras of one state, repeatedly.
    let mut env = task.env()?;
    env.reset(&set.get(0).cloned().unwrap_or(Value::Null))?;
    let mut frame = Vec::with_capacity(camera::OBS_LEN);
    let reps = (env_steps / 10).max(20);
    let t = Instant::now();
    for _ in 0..reps {
        frame.clear();
        camera::capture(&mut env.sim.data, &cams, &mut frame)?;
    }
    let fps = 2.0 * reps as f64 / t.elapsed().as_secs_f64();
    println!(
        "render only: {fps:.0} frames/s ({:.2} ms per frame, one thread)",
        1000.0 / fps
    );
    // Per camera: they see different amounts of geometry (docs/images.md:
    // the front view draws the whole arm in both transparent passes).
    // Timed on the thread's renderer that `capture` used above.
    let model = env.sim.data.model().clone();
    let per_camera = camera::with_renderer(&model, camera::SIZE, camera::SIZE, |r| {
        let mut raw = vec![0u8; camera::SIZE * camera::SIZE * 3];
        cams.iter()
            .zip(camera::CAMERAS)
            .map(|(&cam, name)| {
                let t = Instant::now();
                for _ in 0..reps {
                    r.render_raw(&mut env.sim.data, cam, &mut raw)?;
                }
                Ok(format!(
                    "{name} {:.2} ms",
                    t.elapsed().as_secs_f64() * 1000.0 / reps as f64
                ))
            })
            .collect::<Result<Vec<_>, _>>()
    })?;
    println!("  per camera: {}", per_camera.join(", "));

    // An image-based Aligning evaluation through the engine (lockstep,
    // rendering inside each rollout's step on all threads), with the small
    // image ONNX fixture so that the policy does not dominate.
    let threads = rayon::current_num_threads();
    let (mut policy, info) = load_fixture(&task, "aligning_image", ObsType::Image)?;
    let opts = EvalOptions {
        protocol,
        seed: 0,
        max_live,
        // Time per env step of every rollout, as a stochastic policy needs
        // (the fixture is deterministic and would be simulated once per
        // initial state).
        simulate_every_rollout: true,
        step_cap: smoke.then_some(SMOKE_EVAL_STEPS),
        ..EvalOptions::default()
    };
    let (r, t) = eval::evaluate(&task, &mut policy, &info, &opts, eval::EvalRun::all())?;
    let steps: usize = r.rollouts.iter().map(|x| x.steps).sum();
    let physics = t.step_cpu_s - t.render_cpu_s;
    let physics_ms = 1000.0 * physics / steps as f64;
    let render_ms = 1000.0 * t.render_cpu_s / steps as f64;
    println!(
        "image evaluation ({protocol:?} protocol, {threads} threads): {} rollouts, {steps} env steps in {:.1} s; \
         per env step {physics_ms:.2} ms physics, {render_ms:.2} ms rendering (2 frames), policy {:.2} s",
        r.rollouts.len(),
        t.total_s,
        t.policy_s,
    );

    // A policy that executes chunks of 4 actions with history 2: the frames
    // it never sees are not rendered (docs/images.md).
    let (mut chunked, info) = load_fixture(&task, "aligning_image_k2_h4", ObsType::Image)?;
    let (rc, tc) = eval::evaluate(&task, &mut chunked, &info, &opts, eval::EvalRun::all())?;
    let steps_c: usize = rc.rollouts.iter().map(|x| x.steps).sum();
    println!(
        "chunked image policy (history 2, chunks of 4, aligning_image_k2_h4): {} of {steps_c} env steps rendered, \
         {:.2} ms rendering per env step",
        tc.frames_rendered,
        1000.0 * tc.render_cpu_s / steps_c.max(1) as f64
    );

    // The paper-sized image policy at the batch sizes the engine uses.
    let (resnet, _) = load_fixture(&task, "aligning_resnet18", ObsType::Image)?;
    let mut resnet = resnet;
    let n_set = set.len();
    println!(
        "paper-sized image policy (ResNet-18 per camera + MLP head, aligning_resnet18.onnx), \
         CPU ms per env step (one rollout, one step) at the engine's batch:"
    );
    println!(
        "{:>9} {:>8} {:>6} {:>9} {:>10} {:>8} {:>11}",
        "protocol", "rollouts", "batch", "physics", "rendering", "policy", "policy call"
    );
    let mut batches: Vec<(String, usize, usize)> = Vec::new();
    for p in [ProtocolKind::Quick, ProtocolKind::Paper] {
        let (contexts, per) = eval::protocol_size(&task, p, n_set);
        let n = contexts * per;
        batches.push((format!("{p:?}").to_lowercase(), n, n.min(max_live)));
    }
    batches.push(("(480)".into(), 480, 480));
    if smoke {
        // The quick protocol's batch only: the ResNet at batch 480 alone
        // takes most of a minute in a debug build.
        batches.truncate(1);
    }
    let mut at_480 = f64::NAN;
    for (label, rollouts, batch) in batches {
        let call_s = time_image_policy(&mut resnet, &frame, batch)?;
        if batch == 480 {
            at_480 = call_s;
        }
        println!(
            "{label:>9} {rollouts:>8} {batch:>6} {physics_ms:>9.2} {render_ms:>10.2} {:>8.2} {:>9.0} ms",
            1000.0 * call_s / batch as f64,
            1000.0 * call_s
        );
    }
    if !smoke {
        println!(
            "ResNet-sized policy at batch 480: {:.2} ms per env step",
            1000.0 * at_480 / 480.0
        );
    }
    let (contexts, per) = eval::protocol_size(&task, ProtocolKind::Paper, n_set);
    println!(
        "a deterministic image policy (no `noise` input) is simulated once per initial state: \
         {contexts} of the paper protocol's {} rollouts, so 1/{per} of these physics, rendering and policy costs",
        contexts * per
    );
    println!(
        "ratio rendering/physics time: {:.3}",
        t.render_cpu_s / physics
    );
    Ok(())
}

/// Seconds per call of an image policy on `batch` copies of one rendered
/// observation `frame` (`[2, 3, 96, 96]`), after one warm-up call; at least
/// two timed calls or one second of calls.
fn time_image_policy(policy: &mut OnnxPolicy, frame: &[f32], batch: usize) -> anyhow::Result<f64> {
    let s = policy.shape();
    let ids: Vec<u64> = (0..batch as u64).collect();
    let steps = vec![0u64; batch];
    let obs = vec![0.0f32; batch * s.history * s.obs_dim];
    let mut images = Vec::with_capacity(batch * s.history * frame.len());
    for _ in 0..batch * s.history {
        images.extend_from_slice(frame);
    }
    let mut q = Query::new(&ids, &steps, &obs);
    q.images = Some(&images);
    policy.infer(&q)?;
    let (mut calls, start) = (0, Instant::now());
    while calls < 2 || start.elapsed().as_secs_f64() < 1.0 {
        policy.infer(&q)?;
        calls += 1;
    }
    Ok(start.elapsed().as_secs_f64() / calls as f64)
}

/// Controlled stepping of the Avoiding scene (IK + PD + finger law every
/// substep) versus raw `mj_step` replaying the same controls on the same model.
pub(super) fn physics(env_steps: usize) -> anyhow::Result<()> {
    let task = LoadedTask::load(TaskId::Avoiding)?;
    let mut env = task.env()?;
    let paths: Vec<AvoidingScript> = (0..24).filter_map(AvoidingScript::new).collect();
    let substeps = task.def.n_substeps();

    // Controlled run, recording the controls of every substep for the raw run.
    let mut episode = 0;
    env.reset(&Value::Null)?;
    let start = Instant::now();
    let mut done_steps = 0;
    while done_steps < env_steps {
        let a = paths[episode % paths.len()].act(&env.policy_obs());
        let out = env.step(&a)?;
        done_steps += 1;
        if out.done {
            episode += 1;
            env.reset(&Value::Null)?;
        }
    }
    let controlled = start.elapsed().as_secs_f64();

    // Record every substep's controls of the same episodes (outside the timed region).
    episode = 0;
    let mut recorded = 0;
    let mut ctrl_log: Vec<Vec<[f64; 9]>> = Vec::new();
    env.sim.ctrl_recorder = Some(Vec::new());
    env.reset(&Value::Null)?;
    while recorded < env_steps {
        let a = paths[episode % paths.len()].act(&env.policy_obs());
        let out = env.step(&a)?;
        recorded += 1;
        if out.done || recorded == env_steps {
            episode += 1;
            let mut log = env
                .sim
                .ctrl_recorder
                .replace(Vec::new())
                .unwrap_or_default();
            // The reset's own hold substep is not part of the env steps.
            log.remove(0);
            ctrl_log.push(log);
            env.reset(&Value::Null)?;
        }
    }
    let actuators = task.ids.actuators;

    // Raw mj_step over the same number of physics steps, same model, same starts.
    let mut raw_env = task.env()?;
    let start = Instant::now();
    let mut raw_steps = 0;
    'outer: for ep in &ctrl_log {
        raw_env.reset(&Value::Null)?;
        for ctrl in ep {
            let c = raw_env.sim.data.ctrl_mut();
            for (k, &a) in actuators.iter().enumerate() {
                c[a] = ctrl[k];
            }
            raw_env.sim.data.step()?;
            raw_steps += 1;
            if raw_steps >= env_steps * substeps {
                break 'outer;
            }
        }
    }
    let raw = start.elapsed().as_secs_f64();

    let physics_steps = (env_steps * substeps) as f64;
    let ctrl_rate = physics_steps / controlled;
    let raw_rate = raw_steps as f64 / raw;
    println!("avoiding scene, {env_steps} env steps x {substeps} substeps, scripted paths");
    println!(
        "controlled: {:.0} env steps/s ({:.0} physics steps/s, IK + PD + fingers every substep)",
        env_steps as f64 / controlled,
        ctrl_rate
    );
    println!(
        "raw mj_step: {:.0} physics steps/s (same model, recorded controls)",
        raw_rate
    );
    println!(
        "ratio controlled/raw (physics steps per second): {:.3}",
        ctrl_rate / raw_rate
    );
    Ok(())
}

/// Every agent fixture of assets/fixtures/agents (one per D3IL method family)
/// at batch `batch`: ms per policy call, the projected inference time of
/// Aligning's paper protocol (⌈480 / batch⌉ groups × ⌈400 / E⌉ calls), and the
/// same calls timed in onnxruntime (clients/python/bench_onnxruntime.py
/// `--serve`) on the same files. The two are timed in turn, [`AGENT_ROUNDS`]
/// rounds of [`AGENT_ROUND_S`] each per fixture, and each side's median round
/// counts, so that both see the same load on a shared machine. Last line: the
/// ratio of our total time to onnxruntime's.
pub(super) fn agents_bench(batch: usize, smoke: bool) -> anyhow::Result<()> {
    let (rounds, round_s) = if smoke {
        (1, 0.05)
    } else {
        (AGENT_ROUNDS, AGENT_ROUND_S)
    };
    use std::io::{BufRead, Write};
    let dir = crate::common::assets_dir().join("fixtures").join("agents");
    let task = LoadedTask::load(TaskId::Aligning)?;
    let spec = task.spec();
    let paper = TaskId::Aligning.paper_protocol();
    let wall = d3il_protocol::Limits::default().wall_seconds as f64;
    let groups = (paper.contexts * paper.rollouts).div_ceil(batch.max(1));
    let script = crate::common::assets_dir()
        .join("..")
        .join("clients")
        .join("python")
        .join("bench_onnxruntime.py");
    let mut ort = std::process::Command::new("python3")
        .arg(&script)
        .arg("--serve")
        .arg(&dir)
        .arg(batch.to_string())
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .with_context(|| format!("running {}", script.display()))?;
    let (Some(mut ort_in), Some(ort_out)) = (ort.stdin.take(), ort.stdout.take()) else {
        bail!("no pipes to {}", script.display());
    };
    let mut ort_out = std::io::BufReader::new(ort_out);
    // One onnxruntime timing of `name`; its error output when it fails.
    let mut time_ort = |name: &str| -> anyhow::Result<f64> {
        let mut line = String::new();
        writeln!(ort_in, "{name} {round_s}")
            .and_then(|_| ort_in.flush())
            .and_then(|_| ort_out.read_line(&mut line).map(|_| ()))
            .ok();
        line.trim()
            .parse::<f64>()
            .ok()
            .context("the onnxruntime benchmark stopped (pip install './clients/python[serve]')")
    };
    let mut names: Vec<String> = std::fs::read_dir(&dir)?
        .filter_map(|e| e.ok()?.file_name().into_string().ok())
        .filter_map(|n| n.strip_suffix(".onnx").map(str::to_string))
        .collect();
    names.sort();
    println!(
        "aligning agents at batch {batch}, {} threads; paper protocol {} rollouts x {} steps; default wall limit {wall:.0} s",
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1),
        paper.contexts * paper.rollouts,
        paper.max_steps
    );
    let (mut ours_total, mut ort_total) = (0.0, 0.0);
    for name in &names {
        let bytes = std::fs::read(dir.join(format!("{name}.onnx")))?;
        let manifest: PolicyManifest =
            serde_json::from_slice(&std::fs::read(dir.join(format!("{name}.json")))?)?;
        let mut policy = OnnxPolicy::load(&bytes, &manifest, &spec, 0)?;
        let k = manifest.history;
        let ids: Vec<u64> = (0..batch as u64).collect();
        let steps = vec![10u64; batch];
        let obs: Vec<f32> = (0..batch * k * spec.obs_dim)
            .map(|i| (i as f32 * 0.618).sin())
            .collect();
        let prev = vec![0.001f32; batch * (k - 1) * spec.act_dim];
        let mut q = Query::new(&ids, &steps, &obs);
        if policy.takes_prev_actions() {
            q.prev_actions = Some(&prev);
        }
        policy.infer(&q)?; // plans for this batch are made here
        let (mut ours, mut theirs) = (vec![], vec![]);
        for _ in 0..rounds {
            theirs.push(match time_ort(name) {
                Ok(ms) => ms,
                Err(e) => {
                    let mut err = String::new();
                    let _ = ort.kill();
                    if let Some(mut s) = ort.stderr.take() {
                        let _ = std::io::Read::read_to_string(&mut s, &mut err);
                    }
                    return Err(e.context(err));
                }
            });
            let (mut n, t0) = (0usize, Instant::now());
            while n < 3 || t0.elapsed().as_secs_f64() < round_s {
                policy.infer(&q)?;
                n += 1;
            }
            ours.push(1000.0 * t0.elapsed().as_secs_f64() / n as f64);
        }
        let (ms, ort_ms) = (median(&mut ours), median(&mut theirs));
        let calls = groups * paper.max_steps.div_ceil(manifest.execute);
        let projected = calls as f64 * ms / 1000.0;
        ours_total += calls as f64 * ms;
        ort_total += calls as f64 * ort_ms;
        println!(
            "{name:>18}: k {k} H {} E {}: {ms:9.3} ms/call (onnxruntime {ort_ms:9.3}, x{:.2}); paper protocol {calls} calls = {projected:7.0} s of inference{}",
            manifest.horizon,
            manifest.execute,
            ms / ort_ms,
            if projected > wall { " (OVER the wall limit)" } else { "" }
        );
    }
    drop(ort_in); // end of input: the script exits
    let _ = ort.kill();
    let _ = ort.wait();
    println!(
        "ratio ours/onnxruntime over the paper-protocol inference time of all agents: {:.3} (goal <= 1.0)",
        ours_total / ort_total
    );
    Ok(())
}

/// Rounds of timing per fixture and side in `bench agents`.
const AGENT_ROUNDS: usize = 5;
/// Seconds of calls per round.
const AGENT_ROUND_S: f64 = 0.4;

/// The median of `v` (the mean of the middle two for an even length).
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => f64::NAN,
        _ if n % 2 == 1 => v[n / 2],
        _ => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}
