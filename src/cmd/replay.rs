//! `d3il replay`: replay an episode open-loop and print what our simulator
//! does. Two inputs:
//!
//! * `--result out.json --rollout N`: a stored rollout of an evaluation
//!   (`d3il eval --json`, a shard's part, or the server's replay document:
//!   any JSON object with `manifest` and `rollouts`), replayed from its
//!   trace and checked bit for bit against the record; `--video f.mp4`
//!   writes its video (docs/tasks.md "Replaying a rollout");
//! * `--task T --input ep.json`: `{"context": ..., "actions": [...]}`,
//!   printing observations, TCP and object paths, success and behaviour as
//!   JSON (docs/tasks.md).

use anyhow::{bail, Context};
use d3il_evaluator::open_loop::{replay_actions, OpenLoopOptions};
use d3il_evaluator::replay_input::{Episode, ReplayDoc};
use d3il_evaluator::tasks::LoadedTask;
use d3il_evaluator::trace::{load_task, replay as replay_trace, ReplayCheck};
use d3il_evaluator::video::{render_video, VideoOptions};
use d3il_protocol::perturbation::Axis;
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::TaskId;
use serde_json::{json, Value};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Task to replay in (avoiding, aligning, pushing, ...), with --input.
    #[arg(long, requires = "input", conflicts_with = "result")]
    pub task: Option<TaskId>,
    /// JSON file `{"context": {...}, "actions": [[...], ...]}`; `-` reads stdin.
    #[arg(long, requires = "task")]
    pub input: Option<String>,
    /// A result with rollout traces (`d3il eval --json out.json`, a shard's
    /// part, or any JSON object with `manifest` and `rollouts`); `-` reads stdin.
    #[arg(long, requires = "rollout")]
    pub result: Option<String>,
    /// The rollout to replay: initial state × rollouts per state + index
    /// (the `number` the server's pages and API use).
    #[arg(long, requires = "result")]
    pub rollout: Option<usize>,
    /// With --result: also write the rollout's video (MP4, H.264) here.
    #[arg(long, requires = "result")]
    pub video: Option<PathBuf>,
    /// Side of each camera's picture in the video, pixels.
    #[arg(long, default_value_t = 320)]
    pub video_size: usize,
    /// With --result of a robustness document (`d3il eval --suite
    /// robustness --json`): the level whose rollout to replay, `AXIS/LEVEL`
    /// (e.g. `latency/2`; `AXIS/0` is the control).
    #[arg(long, requires = "result")]
    pub level: Option<String>,
    /// With --result: print the replay's check as JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

fn read(path: &str) -> anyhow::Result<String> {
    if path == "-" {
        std::io::read_to_string(std::io::stdin()).context("reading stdin")
    } else {
        std::fs::read_to_string(path).with_context(|| format!("reading {path}"))
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    match (&args.task, &args.input, &args.result, args.rollout) {
        (Some(task), Some(input), None, _) => {
            let out = replay(*task, &read(input)?)?;
            println!("{}", serde_json::to_string(&out)?);
            Ok(())
        }
        (None, None, Some(result), Some(n)) => {
            if let Some(video) = &args.video {
                crate::common::check_output_path(video, "--video")?;
            }
            if args.video_size == 0 {
                bail!("--video-size must be at least 1 pixel (default 320)");
            }
            let mut text = read(result)?;
            if let Some(level) = &args.level {
                text = level_text(&text, level)?;
            }
            replay_record(&text, n, args.video.as_deref(), args.video_size, args.json)
        }
        _ => bail!(
            "give either --result out.json --rollout N (a stored rollout) or --task T --input ep.json (actions)"
        ),
    }
}

/// Replays rollout `number` of the result document `text`, prints the check,
/// writes the video when asked; an error when it does not replay bit for bit.
pub fn replay_record(
    text: &str,
    number: usize,
    video: Option<&std::path::Path>,
    video_size: usize,
    as_json: bool,
) -> anyhow::Result<()> {
    let doc = ReplayDoc::parse(text)?;
    let (record, trace) = doc.rollout(number)?;
    let task = load_task(&doc.manifest)?;
    let (check, written) = match video {
        Some(path) => {
            let opts = VideoOptions {
                size: video_size,
                ..VideoOptions::default()
            };
            let (check, report) = render_video(&task, &doc.manifest, record, trace, path, &opts)?;
            (check, report.map(|r| (path, r)))
        }
        None => (
            replay_trace(&task, &doc.manifest, record, trace, &mut |_| Ok(()))?,
            None,
        ),
    };
    if as_json {
        println!("{}", serde_json::to_string_pretty(&check)?);
    } else {
        print!("{}", describe(&check));
    }
    if let Some((path, r)) = written {
        eprintln!(
            "wrote {} ({} frames, {}x{}, {:.2} s long, one frame per env step (real time), {} bytes, rendered in {:.1} s)",
            path.display(),
            r.frames,
            r.width,
            r.height,
            r.seconds,
            r.bytes,
            r.render_seconds
        );
    }
    if !check.replays() {
        bail!(
            "rollout {number} does not replay bit for bit: {}",
            check.differences.join("; ")
        );
    }
    Ok(())
}

fn describe(c: &ReplayCheck) -> String {
    let mut s = format!(
        "{} rollout {} (initial state {}, rollout {}): {} steps, success {}, behaviour {}, {}\n",
        c.task.title(),
        c.number,
        c.context_index,
        c.rollout_index,
        c.steps,
        c.success,
        c.behaviour,
        c.ending.describe()
    );
    if c.replays() {
        s.push_str("replays bit for bit: every step's physics state, the outcome and the final object poses equal the record's\n");
    } else {
        for d in &c.differences {
            s.push_str(&format!("differs: {d}\n"));
        }
    }
    s
}

/// Replays `input_json` and returns the output document.
pub fn replay(task: TaskId, input_json: &str) -> anyhow::Result<Value> {
    let loaded = LoadedTask::load(task)?;
    let input = Episode::parse(input_json, &loaded)?;
    let run = replay_actions(
        &loaded,
        &input.context,
        &input.actions,
        OpenLoopOptions::default(),
    )
    .map_err(|e| match e.index {
        Some(i) => anyhow::Error::new(e.source).context(format!("actions[{i}]")),
        None => anyhow::Error::new(e.source).context("field `context`"),
    })?;
    Ok(json!({
        "task": task,
        "observations": run.observations,
        "tcp": run.tcp,
        "joints": run.joints,
        "fingers": run.fingers,
        "objects": run.objects,
        "success": run.success,
        "behaviour": run.behaviour,
        "steps": run.steps,
        "done": run.done,
    }))
}

/// The evaluation of level `spec` (`AXIS/LEVEL`, e.g. `latency/2`; level 0
/// is the control) of a robustness document, as JSON for `d3il replay`.
pub fn level_text(text: &str, spec: &str) -> anyhow::Result<String> {
    let (axis, level) = spec
        .split_once('/')
        .with_context(|| format!("--level {spec}: give AXIS/LEVEL, e.g. latency/2"))?;
    let axis: Axis = axis.parse().map_err(|e: String| anyhow::anyhow!(e))?;
    let level: usize = level
        .parse()
        .with_context(|| format!("--level {spec}: the level is a number (0 is the control)"))?;
    let doc: RobustnessResult = serde_json::from_str(text)
        .context("--level reads a robustness document (`d3il eval --suite robustness --json`)")?;
    let result = doc.level(axis, level).with_context(|| {
        format!(
            "the document has no level {level} of {axis}; it has levels {}",
            doc.levels
                .iter()
                .map(|l| format!("{}/{}", l.axis, l.level))
                .collect::<Vec<_>>()
                .join(", ")
        )
    })?;
    Ok(serde_json::to_string(result)?)
}
