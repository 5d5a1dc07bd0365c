//! Our camera frames of the states in tests/data/reference-frames (the
//! ORIGINAL simulator's 96×96 frames right after reset to Aligning and
//! Stacking test contexts 3-7, rendered by the original code on Mesa
//! llvmpipe; README there) against the original's, through the fidelity
//! report's own comparison (`d3il_evaluator::fidelity::frames`).
//!
//! Measured on 26 November: front 0.980/255 on average (frames 0.964-1.005,
//! 4.3-4.6 % of pixels more than 8/255 off, all of it on the robot), in-hand
//! 0.006/255 (at most 0.047). The floors below are those values rounded up
//! slightly, so that nothing makes our frames drift further away.
//!
//! TARGET (issue 32, item 5): front ≤ 0.5/255. Not reached: the gap is the
//! robot's pixels, mostly the link and hand meshes reduced to 1 000
//! triangles (with the full meshes: 0.36-0.40/255, at several times the
//! rendering cost); docs/images.md "Against the original's frames".

use d3il_evaluator::fidelity::frames::section;
use std::path::Path;

/// Today's front-camera mean, rounded up (/255).
const FRONT_MEAN_FLOOR: f64 = 0.99;
/// Today's worst front frame, rounded up (/255).
const FRONT_FRAME_FLOOR: f64 = 1.02;
/// The bound for the in-hand camera, every frame (/255).
const INHAND_FRAME_BOUND: f64 = 0.1;
/// The target for the front camera (/255), not reached yet.
const FRONT_TARGET: f64 = 0.5;

#[test]
fn our_frames_stay_as_close_to_the_originals_as_today() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/reference-frames");
    let s = section(&dir).expect("compare frames");
    assert_eq!(
        s.robot_look, "meshes",
        "this build draws the robot with primitive shapes; the comparison needs the Panda meshes (./dev installs and converts them, docs/images.md)"
    );
    assert_eq!(
        s.frames.len(),
        20,
        "Aligning and Stacking, contexts 3-7, two cameras"
    );
    for f in &s.frames {
        eprintln!(
            "{} context {} {}: {:.3}/255, {:.2} % of pixels off",
            f.task,
            f.context,
            f.camera,
            f.mean_abs,
            100.0 * f.share_off
        );
    }
    let cam = |name: &str| s.cameras.iter().find(|c| c.camera == name).expect(name);
    let (front, inhand) = (cam("front"), cam("inhand"));
    eprintln!(
        "front {:.3}/255 (target {FRONT_TARGET}, floor {FRONT_MEAN_FLOOR}), in-hand {:.3}/255",
        front.mean_abs, inhand.mean_abs
    );
    assert!(
        front.mean_abs <= FRONT_MEAN_FLOOR,
        "front camera {:.3}/255 from the original's, more than today's {FRONT_MEAN_FLOOR}",
        front.mean_abs
    );
    for f in &s.frames {
        let bound = if f.camera == "front" {
            FRONT_FRAME_FLOOR
        } else {
            INHAND_FRAME_BOUND
        };
        assert!(
            f.mean_abs <= bound,
            "{} context {} {}: {:.3}/255 > {bound}",
            f.task,
            f.context,
            f.camera,
            f.mean_abs
        );
    }
    if front.mean_abs > FRONT_TARGET {
        eprintln!(
            "note: the front camera is {:.3}/255 from the original's; issue 32's target is {FRONT_TARGET}/255",
            front.mean_abs
        );
    }
}
