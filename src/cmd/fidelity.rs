//! `d3il fidelity`: how closely this simulator follows the original D3IL
//! one, computed from the reference data recorded in the original
//! (`tests/data/reference-*`), as Markdown for people or JSON for the
//! server's `/fidelity` page (docs/fidelity.md). The computation is
//! `d3il_evaluator::fidelity`; this file reads the options and writes.

use anyhow::Context;
use d3il_evaluator::fidelity::{compute, DataDirs};
use d3il_protocol::fidelity::{FidelityMode, FidelityReport};
use std::path::PathBuf;

#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    Markdown,
    Json,
}

#[derive(clap::Args)]
pub struct Args {
    /// `markdown` (for people) or `json` (what `d3il serve` shows on /fidelity).
    #[arg(long, value_enum, default_value_t = Format::Markdown)]
    pub format: Format,
    /// Write the report here instead of stdout (written whole, by rename).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// Evaluate the closed-loop policies under the quick protocol (3 initial
    /// states x 2 rollouts) instead of the paper's: seconds instead of
    /// minutes; the report says which.
    #[arg(long)]
    pub quick: bool,
    /// The directory with reference-rollouts/, reference-closed-loop/ and
    /// reference-frames/ (default: $D3IL_REFERENCE_DATA or the repository's tests/data).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Exit when the process that started this one goes away (`d3il serve`
    /// runs the report in the background this way).
    #[arg(long, hide = true)]
    pub exit_with_parent: bool,
}

/// The repository's reference data, as built.
pub fn default_data_dir() -> PathBuf {
    std::env::var_os("D3IL_REFERENCE_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/tests/data")))
}

pub fn run(args: Args) -> anyhow::Result<()> {
    if args.exit_with_parent {
        watch_parent();
    }
    let data = DataDirs {
        root: args.data.unwrap_or_else(default_data_dir),
    };
    anyhow::ensure!(
        data.root.is_dir(),
        "reference data directory {} does not exist; pass --data (the repository's tests/data)",
        data.root.display()
    );
    if let Some(out) = &args.out {
        crate::common::check_output_path(out, "--out")?;
    }
    let mode = if args.quick {
        FidelityMode::Quick
    } else {
        FidelityMode::Full
    };
    let report = compute(&data, mode, &mut |what| eprintln!("fidelity: {what}"))?;
    let text = match args.format {
        Format::Json => serde_json::to_string_pretty(&report)?,
        Format::Markdown => markdown(&report),
    };
    match args.out {
        Some(path) => {
            let tmp = path.with_extension("partial");
            std::fs::write(&tmp, text).with_context(|| format!("writing {}", tmp.display()))?;
            std::fs::rename(&tmp, &path)
                .with_context(|| format!("renaming {} to {}", tmp.display(), path.display()))?;
            eprintln!("wrote {} ({:.0} s)", path.display(), report.seconds);
        }
        None => print!("{text}"),
    }
    Ok(())
}

/// Ends this process when its parent does (it is then re-parented).
fn watch_parent() {
    let parent = std::os::unix::process::parent_id();
    std::thread::spawn(move || loop {
        std::thread::sleep(std::time::Duration::from_secs(1));
        if std::os::unix::process::parent_id() != parent {
            std::process::exit(2);
        }
    });
}

fn yes_no(b: bool) -> &'static str {
    if b {
        "yes"
    } else {
        "no"
    }
}

fn steps_or_end(s: Option<usize>, remaining: usize) -> String {
    match s {
        Some(n) => format!("{n}"),
        None => format!("whole phase ({remaining})"),
    }
}

/// The report as Markdown, written for a researcher.
pub fn markdown(r: &FidelityReport) -> String {
    use std::fmt::Write as _;
    let mut o = String::new();
    let _ = writeln!(
        o,
        "# How closely this simulator follows the original D3IL\n"
    );
    let _ = writeln!(
        o,
        "d3il {}, MuJoCo {}; {} report (closed loop under the {} protocol), computed in {:.0} s from data recorded in the original simulator (ALRhub/d3il, MuJoCo 2.3.2).\n",
        r.d3il_version,
        r.mujoco_version,
        r.mode.as_str(),
        r.closed_loop.protocol,
        r.seconds
    );

    let e = &r.episodes;
    let _ = writeln!(o, "## 1. Recorded episodes replayed here\n");
    let _ = writeln!(
        o,
        "Each episode's actions replayed open-loop from its initial state. Free motion: until a reference object has moved {:.0e} m. Two runs are *together* while every TCP and object position is within {:.0e} m; the contact phase is compared with how long our own replay stays together with itself after qpos[0] is changed by one ulp at reset (contact is chaotic, docs/original-d3il.md §01.7.10).\n",
        e.contact_motion_m, e.together_m
    );
    let _ = writeln!(o, "| episode | steps (orig / here) | success (orig / here) | behaviour (orig / here) | free-motion steps | free-motion TCP error (m) | contact from step | steps together with the original | steps together after a one-ulp change | final object xy gap (m) |");
    let _ = writeln!(o, "|---|---|---|---|---|---|---|---|---|---|");
    for x in &e.episodes {
        let (from, with, ulp, gap) = match &x.contact {
            Some(c) => (
                c.starts_at.to_string(),
                steps_or_end(c.with_original, c.remaining),
                steps_or_end(c.one_ulp, c.remaining),
                format!("{:.2e}", c.final_object_xy_m),
            ),
            None => ("no contact".into(), "–".into(), "–".into(), "–".into()),
        };
        let _ = writeln!(
            o,
            "| {} | {} / {} | {} / {} | {} / {} | {} | {:.1e} | {} | {} | {} | {} |",
            x.file,
            x.steps_original,
            x.steps_here,
            x.success_original,
            x.success_here,
            x.behaviour_original,
            x.behaviour_here,
            x.free_motion_steps,
            x.free_motion_tcp_max_m,
            from,
            with,
            ulp,
            gap
        );
    }

    let c = &r.closed_loop;
    let _ = writeln!(
        o,
        "\n## 2. Closed loop: policies evaluated here against the original\n"
    );
    let _ = writeln!(
        o,
        "Evaluated here under the {} protocol (seed 0); the original ran one rollout per initial state. Numbers agree in distribution; state by state an outcome near a decision boundary flips with the float32 rounding of the inference engine alone.\n",
        c.protocol
    );
    for p in &c.policies {
        let _ = writeln!(o, "### {} ({})\n\n{}\n", p.name, p.task, p.description);
        let _ = writeln!(o, "| | successes | rate | 95 % interval | interval |");
        let _ = writeln!(o, "|---|---|---|---|---|");
        for (who, x) in [("original", &p.original), ("here", &p.here)] {
            let _ = writeln!(
                o,
                "| {who} | {}/{} | {:.3} | {:.3}–{:.3} | {} |",
                x.successes, x.rollouts, x.value, x.ci_low, x.ci_high, x.interval
            );
        }
        let _ = writeln!(
            o,
            "\nHere inside the original's interval: {}; the original inside ours: {}. Over {} initial states ({} rollouts each here): same success in {:.1} % of our rollouts, same behaviour in {:.1} %.\n",
            yes_no(p.here_inside_original_interval),
            yes_no(p.original_inside_here_interval),
            p.contexts,
            p.rollouts_per_context_here,
            100.0 * p.success_agreement,
            100.0 * p.behaviour_agreement
        );
        let whole = p.open_loop.iter().filter(|e| e.whole_episode).count();
        let _ = writeln!(
            o,
            "The original's actions replayed open-loop here: {whole} of {} episodes keep our TCP within {:.0e} m of the original's for the whole episode.\n",
            p.open_loop.len(),
            c.tcp_tolerance_m
        );
        let _ = writeln!(o, "| initial state | original: success, behaviour, steps | here: successes, same behaviour, mean steps | replayed: steps within {:.0e} m / steps | largest TCP gap then (m) | replay ends as the original |", c.tcp_tolerance_m);
        let _ = writeln!(o, "|---|---|---|---|---|---|");
        for (a, b) in p.per_context.iter().zip(&p.open_loop) {
            let _ = writeln!(
                o,
                "| {} | {}, {}, {} | {}/{}, {}/{}, {:.0} | {} / {} | {:.1e} | {} |",
                a.context,
                a.original_success,
                a.original_behaviour,
                a.original_steps,
                a.here_successes,
                a.here_rollouts,
                a.here_same_behaviour,
                a.here_rollouts,
                a.here_mean_steps,
                b.steps_within,
                b.steps_original,
                b.max_within_m,
                yes_no(b.replay_same_success)
            );
        }
        o.push('\n');
    }

    let f = &r.frames;
    let _ = writeln!(o, "## 3. Camera frames against the original's\n");
    let _ = writeln!(
        o,
        "Our 96×96 frames right after reset to the original's test contexts (robot drawn with {}), against the original's frames of the same states rendered by the original code on Mesa llvmpipe. Mean absolute difference over all channels, and the share of pixels with a channel more than {}/255 away. For scale: the original's own frames on a GPU differ from its llvmpipe frames by 1.0-1.2/255 (front) and 1.5-3.7/255 (in-hand).\n",
        f.robot_look, f.off_threshold
    );
    let _ = writeln!(
        o,
        "| camera | frames | mean difference (/255) | largest frame mean (/255) | pixels off |"
    );
    let _ = writeln!(o, "|---|---|---|---|---|");
    for s in &f.cameras {
        let _ = writeln!(
            o,
            "| {} | {} | {:.3} | {:.3} | {:.2} % |",
            s.camera,
            s.frames,
            s.mean_abs,
            s.max_mean_abs,
            100.0 * s.share_off
        );
    }
    let _ = writeln!(
        o,
        "\n| frame | mean difference (/255) | pixels off |\n|---|---|---|"
    );
    for x in &f.frames {
        let _ = writeln!(
            o,
            "| {} context {} {} | {:.3} | {:.2} % |",
            x.task,
            x.context,
            x.camera,
            x.mean_abs,
            100.0 * x.share_off
        );
    }

    let _ = writeln!(o, "\n## 4. Known deviations and what they can change\n");
    for d in &r.deviations {
        let _ = writeln!(o, "- **{}** ({}). {}", d.what, d.source, d.effect);
    }
    o
}
