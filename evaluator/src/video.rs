//! Videos of rollouts, made by replaying their traces ([`crate::trace`]):
//! the front camera and the in-hand camera side by side, one frame per
//! environment state (after the reset, then after every step) at the
//! environment's own rate (one step = the task's substeps of 1 ms: 35 ms,
//! 200/7 frames per second, for most tasks, 30 ms for Stacking; real
//! time), with the step counter and how the rollout ended written on it.
//!
//! Encoding: Debian's `ffmpeg` as a subprocess (libx264, H.264 in MP4 with
//! the index at the front, yuv420p: what every browser's `<video>` plays and
//! can seek), fed raw RGB on stdin. A well-kept encoder we do not have to
//! build or link, and its text overlay (drawtext, DejaVu Sans) draws the
//! counter. The file is written under a temporary name and renamed only when
//! the record replayed bit for bit, so a video never shows a rollout that
//! is not the recorded one.

use crate::camera::{camera_ids, flip_rows};
use crate::mujoco::Renderer;
use crate::tasks::LoadedTask;
use crate::trace::{replay, ReplayCheck, ReplayError};
use d3il_protocol::{Ending, ProtocolManifest, RolloutRecord, RolloutTrace};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

/// Frames per second as ffmpeg's rational `num/den`, and seconds per frame:
/// one frame per environment step of `task` (real time).
fn frame_rate(task: &LoadedTask) -> (usize, usize, f64) {
    let step_ms = task.def.id().step_ms();
    (1000, step_ms, step_ms as f64 / 1000.0)
}

/// The font of the overlay (Debian's fonts-dejavu-core).
const FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

#[derive(Debug, Clone)]
pub struct VideoOptions {
    /// Side of each camera's square picture, pixels (the video is twice as wide).
    pub size: usize,
    /// The encoder (`ffmpeg` on PATH unless set).
    pub ffmpeg: PathBuf,
    /// Multisamples per pixel (None: the scene's own, as the policies'
    /// frames). Videos default to none: at 320 px the edges barely show it,
    /// and llvmpipe renders them about twice as fast.
    pub samples: Option<usize>,
}

impl Default for VideoOptions {
    fn default() -> Self {
        VideoOptions {
            size: 320,
            ffmpeg: PathBuf::from("ffmpeg"),
            samples: Some(0),
        }
    }
}

/// What was written.
#[derive(Debug, Clone, serde::Serialize)]
pub struct VideoReport {
    pub frames: usize,
    pub width: usize,
    pub height: usize,
    pub seconds: f64,
    pub bytes: u64,
    /// Wall-clock seconds spent rendering and encoding.
    pub render_seconds: f64,
}

/// Escapes a path for a drawtext option inside an -vf filter graph.
fn filter_escape(s: &str) -> String {
    let mut out = String::new();
    for c in s.chars() {
        if matches!(c, '\\' | '\'' | ':' | ',' | ';' | '[' | ']' | '=') {
            out.push('\\');
        }
        out.push(c);
    }
    out
}

/// The overlay: title at the top left, the step counter at the top right,
/// the outcome at the bottom. Texts go through files (no escaping of what a
/// record says); `%{frame_num}` is the environment step of the frame.
fn overlay_filter(texts: &[(PathBuf, &str)]) -> String {
    let font = if Path::new(FONT).exists() {
        format!("fontfile={}:", filter_escape(FONT))
    } else {
        String::new()
    };
    texts
        .iter()
        .map(|(file, place)| {
            format!(
                "drawtext={font}textfile={}:{place}:start_number=0:fontsize=15:fontcolor=white:box=1:boxcolor=black@0.55:boxborderw=4",
                filter_escape(&file.to_string_lossy())
            )
        })
        .collect::<Vec<_>>()
        .join(",")
}

fn spawn_encoder(
    opts: &VideoOptions,
    (fps_num, fps_den): (usize, usize),
    width: usize,
    height: usize,
    filter: &str,
    out: &Path,
) -> Result<Child, ReplayError> {
    Command::new(&opts.ffmpeg)
        .args(["-hide_banner", "-loglevel", "error", "-y"])
        .args(["-f", "rawvideo", "-pix_fmt", "rgb24"])
        .args(["-s", &format!("{width}x{height}")])
        .args(["-framerate", &format!("{fps_num}/{fps_den}")])
        .args(["-i", "-", "-vf", filter])
        .args(["-c:v", "libx264", "-preset", "veryfast", "-crf", "23"])
        .args(["-pix_fmt", "yuv420p", "-movflags", "+faststart", "-f", "mp4"])
        .arg(out)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .map_err(|e| {
            ReplayError::Output(format!(
                "cannot start the video encoder `{}`: {e}; install Debian's ffmpeg (./dev installs it)",
                opts.ffmpeg.display()
            ))
        })
}

/// Replays `record` and writes its video to `out` (MP4). Fails, writing
/// nothing, when the record does not replay bit for bit; the check says why.
pub fn render_video(
    task: &LoadedTask,
    manifest: &ProtocolManifest,
    record: &RolloutRecord,
    trace: &RolloutTrace,
    out: &Path,
    opts: &VideoOptions,
) -> Result<(ReplayCheck, Option<VideoReport>), ReplayError> {
    let t0 = std::time::Instant::now();
    let size = opts.size.max(16);
    let (width, height) = (2 * size, size);
    let title = format!(
        "{} - initial state {}, rollout {}",
        task.def.id().title(),
        record.context_index,
        record.rollout_index
    );
    let verdict = if record.success { "success" } else { "failure" };
    let outcome = match record.ending {
        Some(Ending::TaskSuccess) => format!(
            "success: the task ended the episode at step {}",
            record.steps
        ),
        Some(e) => format!("{verdict}: {} at step {}", e.describe(), record.steps),
        None => format!("{verdict} after {} steps", record.steps),
    };
    let tmp = out.with_extension("partial.mp4");
    let texts = [
        (out.with_extension("title.txt"), title.as_str(), "x=8:y=8"),
        (
            out.with_extension("step.txt"),
            "step %{frame_num}",
            "x=w-tw-8:y=8",
        ),
        (
            out.with_extension("outcome.txt"),
            outcome.as_str(),
            "x=8:y=h-th-8",
        ),
    ];
    for (file, text, _) in &texts {
        std::fs::write(file, text)
            .map_err(|e| ReplayError::Output(format!("cannot write {}: {e}", file.display())))?;
    }
    let filter = overlay_filter(
        &texts
            .iter()
            .map(|(f, _, p)| (f.clone(), *p))
            .collect::<Vec<_>>(),
    );
    let (fps_num, fps_den, step_seconds) = frame_rate(task);
    let spawned = spawn_encoder(opts, (fps_num, fps_den), width, height, &filter, &tmp);
    let remove_texts = || {
        for (file, ..) in &texts {
            let _ = std::fs::remove_file(file);
        }
    };
    let mut child = match spawned {
        Ok(c) => c,
        Err(e) => {
            remove_texts();
            return Err(e);
        }
    };
    let mut stdin = child.stdin.take().expect("piped");
    let cams = camera_ids(&task.model)?;
    let mut frame = vec![0u8; width * height * 3];
    let mut raw = vec![0u8; size * size * 3];
    let mut frames = 0usize;
    let mut write_err = None;
    let mut renderer = Renderer::with_samples(task.model.clone(), size, size, opts.samples)?;
    let check = replay(task, manifest, record, trace, &mut |env| {
        for (k, &cam) in cams.iter().enumerate() {
            renderer.render_raw(&mut env.sim.data, cam, &mut raw)?;
            let flipped = flip_rows(&raw, size, size);
            for row in 0..size {
                let dst = (row * width + k * size) * 3;
                frame[dst..dst + size * 3]
                    .copy_from_slice(&flipped[row * size * 3..(row + 1) * size * 3]);
            }
        }
        frames += 1;
        if write_err.is_none() {
            if let Err(e) = stdin.write_all(&frame) {
                write_err = Some(e);
            }
        }
        Ok(())
    });
    drop(stdin);
    let output = child.wait_with_output();
    remove_texts();
    let output = output.map_err(|e| ReplayError::Output(format!("waiting for ffmpeg: {e}")))?;
    let check = match check {
        Ok(c) => c,
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
    };
    if !output.status.success() || write_err.is_some() {
        let _ = std::fs::remove_file(&tmp);
        return Err(ReplayError::Output(format!(
            "ffmpeg failed ({}): {}{}",
            output.status,
            String::from_utf8_lossy(&output.stderr).trim(),
            write_err
                .map(|e| format!(" (writing frames: {e})"))
                .unwrap_or_default()
        )));
    }
    if !check.replays() {
        let _ = std::fs::remove_file(&tmp);
        return Ok((check, None));
    }
    std::fs::rename(&tmp, out)
        .map_err(|e| ReplayError::Output(format!("cannot write {}: {e}", out.display())))?;
    let bytes = std::fs::metadata(out).map(|m| m.len()).unwrap_or(0);
    Ok((
        check,
        Some(VideoReport {
            frames,
            width,
            height,
            seconds: frames as f64 * step_seconds,
            bytes,
            render_seconds: t0.elapsed().as_secs_f64(),
        }),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paths_are_escaped_for_the_filter_graph() {
        assert_eq!(filter_escape("/tmp/a:b,c's"), "/tmp/a\\:b\\,c\\'s");
    }
}
