//! `d3il demos`: the scripted experts recorded on training initial states, in
//! the D3IL reference code's own dataset format (evaluator/src/demos, docs/zoo.md).

use anyhow::Context;
use d3il_evaluator::demos::{self, DemoOptions, DEMOS_VERSION};
use d3il_evaluator::tasks::{contexts::sha256_hex, LoadedTask};
use d3il_protocol::TaskId;
use serde_json::json;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Task: avoiding, aligning, pushing, sorting-2, sorting-4, sorting-6, stacking.
    #[arg(long)]
    pub task: TaskId,
    /// Successful episodes to write (behaviours in turn, so every one the task counts is covered).
    #[arg(long)]
    pub episodes: usize,
    /// Seed of the training states, speeds and noise: the same seed gives the same bytes.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Directory to write (must not exist or be empty); laid out as the
    /// reference checkout's `environments/dataset/data/<task>/`.
    #[arg(long)]
    pub out: PathBuf,
    /// Action noise: standard deviation relative to the expert action's norm.
    #[arg(long, default_value_t = DemoOptions::default().noise)]
    pub noise: f64,
    /// Speed factors are uniform in [c (1 - s), c (1 + s)] with c = --speed.
    #[arg(long, default_value_t = 0.15)]
    pub speed_spread: f64,
    /// Centre c of the speed factors: above 1 where the expert at its own
    /// pace runs longer than the reference config's `max_len_data` (Sorting-4).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.episodes == 0 {
        anyhow::bail!("--episodes must be at least 1");
    }
    if !(0.0..1.0).contains(&args.speed_spread) {
        anyhow::bail!(
            "--speed-spread {} must be in [0, 1): speeds are drawn from [1 - s, 1 + s]",
            args.speed_spread
        );
    }
    if !(0.5..=2.0).contains(&args.speed) {
        anyhow::bail!(
            "--speed {} must be in [0.5, 2]: it scales the expert's actions",
            args.speed
        );
    }
    if !(0.0..=1.0).contains(&args.noise) {
        anyhow::bail!("--noise {} must be in [0, 1]", args.noise);
    }
    let layout = demos::layout(args.task)?;
    demos::expert_name(args.task)?;
    if args.out.exists()
        && std::fs::read_dir(&args.out)
            .with_context(|| format!("--out {}", args.out.display()))?
            .next()
            .is_some()
    {
        anyhow::bail!(
            "--out {}: exists and is not empty; give a new directory (nothing was written)",
            args.out.display()
        );
    }
    let opts = DemoOptions {
        episodes: args.episodes,
        seed: args.seed,
        speed: (
            args.speed * (1.0 - args.speed_spread),
            args.speed * (1.0 + args.speed_spread),
        ),
        noise: args.noise,
        ..DemoOptions::default()
    };
    let task = LoadedTask::load(args.task)?;
    let t0 = std::time::Instant::now();
    let (episodes, attempts) = demos::record(&task, &opts)?;
    let hist = demos::histogram(&episodes);
    let n_behaviours = args.task.n_behaviours();

    let ep_dir = args.out.join(layout.episode_dir);
    std::fs::create_dir_all(&ep_dir).with_context(|| format!("creating {}", ep_dir.display()))?;
    let mut files = serde_json::Map::new();
    let mut write = |rel: &str, bytes: &[u8]| -> anyhow::Result<()> {
        let path = args.out.join(rel);
        std::fs::write(&path, bytes).with_context(|| format!("writing {}", path.display()))?;
        files.insert(rel.to_string(), json!(sha256_hex(bytes)));
        Ok(())
    };
    let mut names = Vec::new();
    let mut listing = Vec::new();
    for ep in &episodes {
        let name = format!("demo_{:04}.pkl", ep.index);
        write(
            &format!("{}/{name}", layout.episode_dir),
            &demos::episode_pickle(args.task, ep)?,
        )?;
        listing.push(json!({
            "file": name, "behaviour": ep.behaviour, "steps": ep.steps,
            "speed": ep.speed, "variant": ep.variant, "attempt": ep.attempt,
            "context": ep.context,
        }));
        names.push(name);
    }
    let n_eval = ((names.len() as f64 * opts.eval_fraction).ceil() as usize).clamp(1, names.len());
    let split = names.len() - n_eval;
    if let Some((train, eval)) = layout.lists {
        // Train on all but the last `n_eval` episodes; the reference's
        // validation loss reads the rest.
        write(train, &demos::file_list_pickle(&names[..split.max(1)]))?;
        write(eval, &demos::file_list_pickle(&names[split..]))?;
    }
    let set = task.def.context_set()?;
    let manifest = json!({
        "demos_version": DEMOS_VERSION,
        "task": args.task.slug(),
        "task_version": task.def.version(),
        "generator": {
            "command": format!(
                "d3il demos --task {} --episodes {} --seed {} --noise {} --speed-spread {}{}",
                args.task.slug(), args.episodes, args.seed, args.noise, args.speed_spread,
                if args.speed == 1.0 { String::new() } else { format!(" --speed {}", args.speed) }
            ),
            "git_commit": crate::common::build::GIT_COMMIT,
            "expert": demos::expert_name(args.task)?,
        },
        "options": opts,
        "episodes": episodes.len(),
        "steps": episodes.iter().map(|e| e.steps).sum::<usize>(),
        "attempts": attempts,
        "behaviours": {
            "counted_by_task": n_behaviours,
            "covered": hist.len(),
            "histogram": hist,
        },
        "training_states": if args.task == TaskId::Avoiding {
            json!("Avoiding has one fixed start (no context): episodes differ by path, speed and noise only")
        } else {
            json!(format!(
                "drawn from the task's context distribution (ChaCha8, seed {} with one stream per episode and try); \
                 none equal to an initial state of the test set {} (sha256 {})",
                args.seed, set.file.version, set.sha256
            ))
        },
        "reference_layout": {
            "data_dir": format!("environments/dataset/data/{}", layout.root),
            "episode_dir": layout.episode_dir,
            "train_list": layout.lists.map(|l| l.0),
            "eval_list": layout.lists.map(|l| l.1),
            "max_len_data": layout.max_len_data,
            "eval_episodes": if layout.lists.is_some() { n_eval } else { 0 },
        },
        "files": files,
        "episode_list": listing,
    });
    let text = serde_json::to_string_pretty(&manifest)? + "\n";
    std::fs::write(args.out.join("manifest.json"), &text)?;
    eprintln!(
        "{} episodes of {} ({} steps; {} tries, {} failed, {} too long, {} unlabeled) in {:.1} s; behaviours {}/{}: {}",
        episodes.len(),
        args.task,
        manifest["steps"],
        attempts.tried,
        attempts.failed,
        attempts.too_long,
        attempts.unlabeled,
        t0.elapsed().as_secs_f64(),
        hist.len(),
        n_behaviours,
        hist.iter()
            .map(|(k, v)| format!("{k}:{v}"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    println!(
        "{}  manifest sha256 {}",
        args.out.join("manifest.json").display(),
        sha256_hex(text.as_bytes())
    );
    if hist.len() < n_behaviours {
        eprintln!(
            "warning: {} of the {n_behaviours} behaviours {} counts are covered; record more episodes",
            hist.len(),
            args.task
        );
    }
    Ok(())
}
