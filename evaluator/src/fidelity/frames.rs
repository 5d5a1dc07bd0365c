//! (c) Images: our frames of the states in `reference-frames/` (the two
//! cameras right after reset to an original test context,
//! `<task>_ctx<i>_<front|inhand>.png`, RGB rows top-down) against the
//! original's, per camera: mean absolute difference and the share of
//! pixels off by more than 8/255 (the measures of docs/images.md).

use super::FidelityError;
use crate::camera;
use crate::sim::scene::best_look;
use crate::tasks::LoadedTask;
use d3il_protocol::fidelity::{CameraSummary, FrameFidelity, FramesSection};
use d3il_protocol::{ObsType, RobotLook, TaskId};
use std::collections::BTreeMap;
use std::path::Path;

/// A pixel is "off" when a channel differs by more than this (/255).
pub const OFF_THRESHOLD: u8 = 8;

/// Camera names of the reference files, in the order of [`camera::CAMERAS`].
pub const CAMERA_NAMES: [&str; 2] = ["front", "inhand"];

/// Mean absolute difference (in 1/255) over all channels, and the share
/// of pixels with a channel more than [`OFF_THRESHOLD`] away.
pub fn compare_rgb(a: &[u8], b: &[u8]) -> (f64, f64) {
    assert_eq!(a.len(), b.len(), "same image size");
    let sum: u64 = a.iter().zip(b).map(|(x, y)| x.abs_diff(*y) as u64).sum();
    let off = a
        .chunks(3)
        .zip(b.chunks(3))
        .filter(|(p, q)| {
            p.iter()
                .zip(*q)
                .any(|(x, y)| x.abs_diff(*y) > OFF_THRESHOLD)
        })
        .count();
    (
        sum as f64 / a.len() as f64,
        off as f64 / (a.len() / 3) as f64,
    )
}

/// Decodes an 8-bit RGB (or RGBA) PNG to RGB bytes and its size.
pub fn read_png_rgb(path: &Path) -> Result<(Vec<u8>, usize, usize), FidelityError> {
    let file = std::fs::File::open(path).map_err(|e| FidelityError::data(path, e))?;
    let mut reader = png::Decoder::new(std::io::BufReader::new(file))
        .read_info()
        .map_err(|e| FidelityError::data(path, e))?;
    let mut buf = vec![0; reader.output_buffer_size().unwrap_or(0)];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| FidelityError::data(path, e))?;
    let (w, h) = (info.width as usize, info.height as usize);
    let rgb = match (info.color_type, info.bit_depth) {
        (png::ColorType::Rgb, png::BitDepth::Eight) => buf[..w * h * 3].to_vec(),
        (png::ColorType::Rgba, png::BitDepth::Eight) => buf[..w * h * 4]
            .chunks(4)
            .flat_map(|p| [p[0], p[1], p[2]])
            .collect(),
        other => {
            return Err(FidelityError::data(
                path,
                format!("expected an 8-bit RGB PNG, found {other:?}"),
            ))
        }
    };
    Ok((rgb, w, h))
}

/// Our two camera frames (RGB, rows top-down) right after reset to initial
/// state `context` of `task`'s set, drawn as image evaluations draw them.
pub fn our_frames(
    task: &LoadedTask,
    context: usize,
    size: usize,
) -> Result<[Vec<u8>; 2], FidelityError> {
    let set = task.def.context_set()?;
    let ctx = set.get(context).ok_or_else(|| FidelityError::Data {
        path: "reference-frames".into(),
        message: format!("{} has no initial state {context}", task.def.id()),
    })?;
    let mut env = task.env()?;
    env.reset(ctx)?;
    let cams = camera::camera_ids(&task.model)?;
    Ok([
        camera::render_rgb(&mut env.sim.data, cams[0], size)?,
        camera::render_rgb(&mut env.sim.data, cams[1], size)?,
    ])
}

/// `aligning_ctx3_front.png` → (aligning, 3, front camera index 0).
fn parse_name(file: &str) -> Option<(TaskId, usize, usize)> {
    let stem = file.strip_suffix(".png")?;
    let (rest, cam) = stem.rsplit_once('_')?;
    let (task, ctx) = rest.rsplit_once("_ctx")?;
    let cam = CAMERA_NAMES.iter().position(|c| *c == cam)?;
    Some((task.replace('_', "-").parse().ok()?, ctx.parse().ok()?, cam))
}

/// Every reference frame in `dir` compared with ours.
pub fn section(dir: &Path) -> Result<FramesSection, FidelityError> {
    let mut files: Vec<(TaskId, usize, usize, std::path::PathBuf)> = std::fs::read_dir(dir)
        .map_err(|e| FidelityError::data(dir, e))?
        .flatten()
        .filter_map(|e| {
            let name = e.file_name().to_str()?.to_string();
            parse_name(&name).map(|(t, c, k)| (t, c, k, e.path()))
        })
        .collect();
    files.sort_by_key(|a| (a.0.to_string(), a.1, a.2));
    if files.is_empty() {
        return Err(FidelityError::data(
            dir,
            "no frames (<task>_ctx<i>_<front|inhand>.png)",
        ));
    }
    let look = best_look();
    let mut tasks: BTreeMap<String, LoadedTask> = BTreeMap::new();
    let mut frames = vec![];
    for (task, ctx, cam, path) in files {
        let loaded = match tasks.entry(task.to_string()) {
            std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
            std::collections::btree_map::Entry::Vacant(e) => {
                e.insert(LoadedTask::load_look(task, ObsType::Image, look)?)
            }
        };
        let (theirs, w, h) = read_png_rgb(&path)?;
        if w != h {
            return Err(FidelityError::data(&path, format!("{w}x{h} is not square")));
        }
        let ours = our_frames(loaded, ctx, w)?;
        let (mean_abs, share_off) = compare_rgb(&ours[cam], &theirs);
        frames.push(FrameFidelity {
            task: task.to_string(),
            context: ctx,
            camera: CAMERA_NAMES[cam].into(),
            mean_abs,
            share_off,
        });
    }
    let cameras = CAMERA_NAMES
        .iter()
        .map(|c| {
            let of: Vec<&FrameFidelity> = frames.iter().filter(|f| f.camera == *c).collect();
            let n = of.len().max(1) as f64;
            CameraSummary {
                camera: c.to_string(),
                frames: of.len(),
                mean_abs: of.iter().map(|f| f.mean_abs).sum::<f64>() / n,
                max_mean_abs: of.iter().map(|f| f.mean_abs).fold(0.0, f64::max),
                share_off: of.iter().map(|f| f.share_off).sum::<f64>() / n,
            }
        })
        .collect();
    Ok(FramesSection {
        robot_look: match look {
            RobotLook::Meshes => "meshes".into(),
            RobotLook::Primitives => "primitives".into(),
        },
        off_threshold: OFF_THRESHOLD,
        frames,
        cameras,
    })
}
