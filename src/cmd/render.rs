//! `d3il render`: what an image policy sees. Renders the two policy cameras
//! (front `bp_cam`, in-hand `rgbd_rb0`) after resetting a task to one of its
//! fixed initial states, and writes them side by side as a PNG.

use crate::common::flags::Look;
use anyhow::Context;
use d3il_evaluator::camera;
use d3il_evaluator::sim::scene::RobotLook;
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::{ObsType, TaskId};
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Task: aligning, sorting-4, sorting-6, stacking (the image tasks); the
    /// other tasks render too, for inspection.
    #[arg(long)]
    pub task: TaskId,
    /// Index into the task's fixed initial-state set.
    #[arg(long, default_value_t = 0)]
    pub context: usize,
    /// Output PNG: front view on the left, in-hand view on the right.
    #[arg(long)]
    pub out: PathBuf,
    /// Side of each camera image in pixels (policies see 96).
    #[arg(long, default_value_t = camera::SIZE)]
    pub size: usize,
    /// Env steps with zero action before rendering (the robot settles).
    #[arg(long, default_value_t = 0)]
    pub steps: usize,
    /// Robot: `meshes` (the Panda's links, hand and fingers, from
    /// example-robot-data, when this build has them), `primitives` (capsules
    /// and boxes), or `best` (what image evaluations use: meshes when
    /// available).
    #[arg(long, value_enum, default_value_t = Look::Best)]
    pub look: Look,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.size == 0 || args.size > 2048 {
        anyhow::bail!("--size must be between 1 and 2048 pixels (policies see 96)");
    }
    let obs = if args.task.has_image_variant() {
        ObsType::Image
    } else {
        ObsType::State
    };
    crate::common::check_output_path(&args.out, "--out")?;
    // The initial state is looked up before the scene is compiled.
    let set = d3il_evaluator::tasks::task_def(args.task)?.context_set()?;
    let context = set.get(args.context).with_context(|| {
        format!(
            "--context {} is out of range: the {} set has {} initial states (0..{})",
            args.context,
            args.task,
            set.len(),
            set.len().saturating_sub(1)
        )
    })?;
    let look = args.look.robot_look();
    let task = LoadedTask::load_look(args.task, obs, look)?;
    let mut env = task.env()?;
    env.reset(context)?;
    let zero = vec![0.0f32; task.def.act_dim()];
    for _ in 0..args.steps {
        if env.is_done() {
            break;
        }
        env.step(&zero)?;
    }
    let cams = camera::camera_ids(&task.model)?;
    let n = args.size;
    let mut views = Vec::new();
    for cam in cams {
        views.push(camera::render_rgb(&mut env.sim.data, cam, n)?);
    }
    // Side by side: row y of the output = row y of view 0, then of view 1.
    let mut out = Vec::with_capacity(2 * n * n * 3);
    for y in 0..n {
        for v in &views {
            out.extend_from_slice(&v[y * n * 3..(y + 1) * n * 3]);
        }
    }
    let png = camera::encode_png(&out, 2 * n, n).map_err(|e| anyhow::anyhow!(e))?;
    std::fs::write(&args.out, png).with_context(|| format!("writing {}", args.out.display()))?;
    eprintln!(
        "wrote {} ({}x{}: {} | {}) for {} context {}, {} robot{}",
        args.out.display(),
        2 * n,
        n,
        camera::CAMERAS[0],
        camera::CAMERAS[1],
        args.task,
        args.context,
        match look {
            RobotLook::Meshes => "meshed",
            RobotLook::Primitives => "primitive",
        },
        if obs == ObsType::State {
            " (this task has no image variant; shown for inspection)"
        } else {
            ""
        }
    );
    Ok(())
}
