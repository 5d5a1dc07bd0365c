//! Image observations (docs/original-d3il.md §01.6): the two 96 × 96 cameras of the vision
//! variants and the reference's image pipeline.
//!
//! * camera 0: `bp_cam`, the static front view; camera 1: `rgbd_rb0`, in-hand;
//! * MuJoCo returns RGB rows bottom-up; the reference flips vertically,
//!   converts RGB → BGR (OpenCV), transposes to C×H×W and divides by 255.
//!
//! Rendering uses one [`Renderer`] per thread (an OpenGL context is current on
//! one thread); all rollouts stepped on that thread share it.

use crate::mujoco::{Data, MjError, Model, ObjKind, Renderer};
use std::cell::RefCell;
use std::sync::Arc;

/// Side of the square images the vision variants use.
pub const SIZE: usize = 96;
/// Camera names in the order of the policy's camera axis.
pub const CAMERAS: [&str; 2] = ["bp_cam", "rgbd_rb0"];
/// Floats of one observation: 2 cameras × 3 channels × 96 × 96.
pub const OBS_LEN: usize = 2 * 3 * SIZE * SIZE;

thread_local! {
    static RENDERER: RefCell<Option<Renderer>> = const { RefCell::new(None) };
}

/// Runs `f` with this thread's renderer for `model` at `width` × `height`,
/// creating (or replacing) it when needed.
pub fn with_renderer<R>(
    model: &Arc<Model>,
    width: usize,
    height: usize,
    f: impl FnOnce(&mut Renderer) -> Result<R, MjError>,
) -> Result<R, MjError> {
    RENDERER.with(|cell| {
        let mut slot = cell.borrow_mut();
        let fits = slot.as_ref().is_some_and(|r| {
            Arc::ptr_eq(r.model(), model) && r.width() == width && r.height() == height
        });
        if !fits {
            *slot = None; // free the old context before making a new one
            *slot = Some(Renderer::new(model.clone(), width, height)?);
        }
        f(slot.as_mut().expect("set above"))
    })
}

/// The ids of the two policy cameras in `model`.
pub fn camera_ids(model: &Model) -> Result<[usize; 2], MjError> {
    Ok([
        model.id(ObjKind::Camera, CAMERAS[0])?,
        model.id(ObjKind::Camera, CAMERAS[1])?,
    ])
}

/// Renders camera `camera` at `size` × `size` and returns RGB bytes, rows
/// top-down (the flipped image, before the BGR conversion): for PNG output.
pub fn render_rgb(data: &mut Data, camera: usize, size: usize) -> Result<Vec<u8>, MjError> {
    let mut raw = vec![0u8; size * size * 3];
    let model = data.model().clone();
    with_renderer(&model, size, size, |r| r.render_raw(data, camera, &mut raw))?;
    Ok(flip_rows(&raw, size, size))
}

/// Appends the policy image observation of both cameras (`[2, 3, 96, 96]`,
/// BGR, [0, 1]) rendered from the current state of `data`.
pub fn capture(data: &mut Data, cameras: &[usize; 2], out: &mut Vec<f32>) -> Result<(), MjError> {
    let model = data.model().clone();
    let mut raw = vec![0u8; SIZE * SIZE * 3];
    with_renderer(&model, SIZE, SIZE, |r| {
        for &cam in cameras {
            r.render_raw(data, cam, &mut raw)?;
            append_policy_layout(&raw, SIZE, SIZE, out);
        }
        Ok(())
    })
}

/// Encodes top-down RGB bytes (`width` × `height` × 3) as a PNG file.
pub fn encode_png(rgb: &[u8], width: usize, height: usize) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().map_err(|e| e.to_string())?;
        w.write_image_data(rgb).map_err(|e| e.to_string())?;
    }
    Ok(out)
}

/// Reverses the row order of a width × height × 3 image.
pub fn flip_rows(raw: &[u8], width: usize, height: usize) -> Vec<u8> {
    let row = width * 3;
    let mut out = Vec::with_capacity(raw.len());
    for y in (0..height).rev() {
        out.extend_from_slice(&raw[y * row..(y + 1) * row]);
    }
    out
}

/// The reference pipeline on one bottom-up RGB frame: flip vertically, RGB →
/// BGR, H×W×C → C×H×W, / 255. Appends 3 × height × width floats.
pub fn append_policy_layout(raw: &[u8], width: usize, height: usize, out: &mut Vec<f32>) {
    let start = out.len();
    out.resize(start + 3 * width * height, 0.0);
    let planes = &mut out[start..];
    for y in 0..height {
        let src_row = height - 1 - y; // vertical flip
        for x in 0..width {
            let p = (src_row * width + x) * 3;
            for c in 0..3 {
                // channel c of BGR is channel 2 - c of RGB
                planes[c * width * height + y * width + x] = raw[p + 2 - c] as f32 / 255.0;
            }
        }
    }
}

/// Projects world point `p` into camera `camera`'s image (`size` × `size`,
/// top-down rows): returns (column, row) in pixels, or None behind the camera.
/// Pinhole model of docs/original-d3il.md §01.6: the camera looks along its −z axis, +x is
/// image-right, +y image-up, f = (size/2) / tan(fovy/2).
pub fn project(data: &Data, camera: usize, p: [f64; 3], size: usize) -> Option<(f64, f64)> {
    let pos = data.cam_xpos(camera);
    let r = data.cam_xmat(camera); // row-major 3x3, columns are the camera axes
    let d = [p[0] - pos[0], p[1] - pos[1], p[2] - pos[2]];
    // Camera-frame coordinates: R^T d.
    let cx = r[0] * d[0] + r[3] * d[1] + r[6] * d[2];
    let cy = r[1] * d[0] + r[4] * d[1] + r[7] * d[2];
    let cz = r[2] * d[0] + r[5] * d[1] + r[8] * d[2];
    if cz >= 0.0 {
        return None;
    }
    let fovy = data.model().cam_fovy(camera).to_radians();
    let f = (size as f64 / 2.0) / (fovy / 2.0).tan();
    let u = size as f64 / 2.0 + f * cx / -cz;
    let v = size as f64 / 2.0 - f * cy / -cz;
    Some((u, v))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pipeline_flips_swaps_channels_and_scales() {
        // 2x2 image, bottom-up rows: bottom row red, top row blue.
        let raw = [255, 0, 0, 255, 0, 0, 0, 0, 255, 0, 0, 255];
        let mut out = vec![];
        append_policy_layout(&raw, 2, 2, &mut out);
        // Channel 0 is blue: the top row (first after the flip) is blue.
        assert_eq!(&out[0..4], &[1.0, 1.0, 0.0, 0.0]);
        // Channel 1 (green) is empty.
        assert_eq!(&out[4..8], &[0.0; 4]);
        // Channel 2 is red: bottom row.
        assert_eq!(&out[8..12], &[0.0, 0.0, 1.0, 1.0]);
        let flipped = flip_rows(&raw, 2, 2);
        assert_eq!(&flipped[0..3], &[0, 0, 255]);
    }
}
