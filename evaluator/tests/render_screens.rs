//! Renderers that exist at the same time draw on EGL displays of their own,
//! one llvmpipe screen each (a screen rasterizes one frame at a time, so
//! worker threads sharing one would take turns; docs/images.md), and every
//! display gives the same pixels. Alone in its binary: the test counts the
//! process's displays, which other tests' renderers would hold.

use d3il_evaluator::camera::{camera_ids, SIZE};
use d3il_evaluator::mujoco::Renderer;
use d3il_evaluator::tasks::LoadedTask;
use d3il_protocol::{ObsType, TaskId};
use std::sync::{Arc, Barrier};

#[test]
fn renderers_alive_at_once_get_screens_of_their_own_and_the_same_pixels() {
    // The state variant: its environments render nothing themselves, so the
    // renderers below are the only ones in the process.
    let task = Arc::new(LoadedTask::load_obs(TaskId::Aligning, ObsType::State).unwrap());
    // Four renderers at once: Mesa 22.3 makes four displays on its software
    // device (device and surfaceless platform, each without and with an
    // empty attribute list); a fifth shares the least used one.
    let n = 5;
    let all_alive = Arc::new(Barrier::new(n));
    let threads: Vec<_> = (0..n)
        .map(|_| {
            let (task, all_alive) = (task.clone(), all_alive.clone());
            std::thread::spawn(move || {
                let set = task.def.context_set().unwrap();
                let mut env = task.env().unwrap();
                env.reset(set.get(2).unwrap()).unwrap();
                let mut r = Renderer::new(task.model.clone(), SIZE, SIZE).unwrap();
                all_alive.wait();
                let mut frames = Vec::new();
                for cam in camera_ids(&task.model).unwrap() {
                    let mut rgb = vec![0u8; SIZE * SIZE * 3];
                    r.render_raw(&mut env.sim.data, cam, &mut rgb).unwrap();
                    frames.push(rgb);
                }
                let slot = r.display_slot();
                all_alive.wait(); // keep every renderer until all have drawn
                (slot, frames)
            })
        })
        .collect();
    let results: Vec<_> = threads.into_iter().map(|t| t.join().unwrap()).collect();
    let mut slots: Vec<usize> = results.iter().map(|r| r.0).collect();
    slots.sort();
    assert_eq!(
        slots,
        vec![0, 0, 1, 2, 3],
        "four displays, the fifth renderer on the least used"
    );
    for (slot, frames) in &results[1..] {
        assert_eq!(
            frames, &results[0].1,
            "display {slot} drew other pixels than display {}",
            results[0].0
        );
    }
    // A renderer made after the others are gone reuses a free display.
    let r = Renderer::new(task.model.clone(), SIZE, SIZE).unwrap();
    assert!(r.display_slot() < 4);
}
