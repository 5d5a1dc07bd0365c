//! `d3il bench video`: what keeping rollouts replayable costs. The size of a
//! paper-protocol result with its rollout traces, then the seconds to render
//! one rollout's video (replay + both cameras at 320 px + H.264 encoding)
//! against the seconds to simulate the same rollout, scaled to 400 steps.

use d3il_evaluator::eval::{self, EvalOptions};
use d3il_evaluator::tasks::LoadedTask;
use d3il_evaluator::trace::{load_task, replay};
use d3il_evaluator::video::{render_video, VideoOptions};
use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use std::time::Instant;

const MIB: f64 = (1 << 20) as f64;

pub fn run(protocol: ProtocolKind) -> anyhow::Result<()> {
    let task = LoadedTask::load(TaskId::Aligning)?;
    let (mut policy, info) = super::fixtures::load_fixture(&task, "aligning_mlp", ObsType::State)?;
    let opts = EvalOptions {
        protocol,
        ..EvalOptions::default()
    };
    let t0 = Instant::now();
    let (result, _) = eval::evaluate(&task, &mut policy, &info, &opts, eval::EvalRun::all())?;
    let json = serde_json::to_vec(&result)?;
    let traces: Vec<usize> = result
        .rollouts
        .iter()
        .filter_map(|r| r.trace.as_ref())
        .map(|t| serde_json::to_vec(t).map(|v| v.len()).unwrap_or(0))
        .collect();
    let mean_trace = traces.iter().sum::<usize>() as f64 / traces.len().max(1) as f64;
    let untraced: usize = json.len() - traces.iter().sum::<usize>();
    println!(
        "aligning, protocol {protocol:?}, BC-MLP fixture (deterministic: {} of {} rollouts simulated) in {:.1} s",
        traces.len(),
        result.rollouts.len(),
        t0.elapsed().as_secs_f64()
    );
    println!(
        "result with rollout traces: {:.2} MiB of JSON ({} traces of {:.1} KiB on average; {:.2} MiB without them); \
         with every rollout simulated (a stochastic policy): {:.2} MiB",
        json.len() as f64 / MIB,
        traces.len(),
        mean_trace / 1024.0,
        untraced as f64 / MIB,
        (untraced as f64 + mean_trace * result.rollouts.len() as f64) / MIB
    );
    // The longest traced rollout, rendered and simulated.
    let record = result
        .rollouts
        .iter()
        .filter(|r| r.trace.is_some())
        .max_by_key(|r| r.steps)
        .ok_or_else(|| anyhow::anyhow!("no rollout has a trace"))?;
    let trace = record.trace.as_deref().expect("filtered");
    let task = load_task(&result.manifest)?;
    let mut sim_s = f64::INFINITY;
    for _ in 0..3 {
        let t = Instant::now();
        let check = replay(&task, &result.manifest, record, trace, &mut |_| Ok(()))?;
        sim_s = sim_s.min(t.elapsed().as_secs_f64());
        anyhow::ensure!(
            check.replays(),
            "the rollout does not replay: {:?}",
            check.differences
        );
    }
    let dir = std::env::temp_dir().join(format!("d3il-bench-video-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let out = dir.join("rollout.mp4");
    let mut video_s = f64::INFINITY;
    let mut last = None;
    for _ in 0..2 {
        let t = Instant::now();
        let (_, report) = render_video(
            &task,
            &result.manifest,
            record,
            trace,
            &out,
            &VideoOptions::default(),
        )?;
        video_s = video_s.min(t.elapsed().as_secs_f64());
        last = report;
    }
    let _ = std::fs::remove_dir_all(&dir);
    let report = last.ok_or_else(|| anyhow::anyhow!("no video was written"))?;
    let scale = 400.0 / record.steps.max(1) as f64;
    println!(
        "rollout {} ({} steps): simulation {:.3} s, video {:.2} s ({} frames {}x{}, {:.2} s long, {:.0} KiB)",
        record.number(result.manifest.rollouts_per_context),
        record.steps,
        sim_s,
        video_s,
        report.frames,
        report.width,
        report.height,
        report.seconds,
        report.bytes as f64 / 1024.0
    );
    println!(
        "video: {:.2} s per 400-step rollout video (simulation {:.3} s), ratio {:.1}",
        video_s * scale,
        sim_s * scale,
        video_s / sim_s
    );
    Ok(())
}
