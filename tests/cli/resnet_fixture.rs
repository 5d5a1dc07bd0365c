//! The paper-sized image policy fixture (`aligning_resnet18.onnx`, built by
//! scripts/make_fixtures.py: a ResNet-18 encoder per camera, features
//! concatenated with the low-dim obs, an MLP head) passes the evaluator's
//! model checks, runs in tract on rendered observations and depends on the
//! pixels, so `d3il bench render` times a real image network.

use d3il_evaluator::camera;
use d3il_evaluator::tasks::LoadedTask;
use d3il_policy::{OnnxPolicy, Policy, Query};
use d3il_protocol::{ObsType, PolicyManifest, TaskId};

#[test]
fn resnet18_fixture_runs_on_rendered_images() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets/fixtures");
    let bytes = std::fs::read(dir.join("aligning_resnet18.onnx")).unwrap();
    let manifest: PolicyManifest =
        serde_json::from_slice(&std::fs::read(dir.join("aligning_resnet18.json")).unwrap())
            .unwrap();
    assert_eq!(manifest.obs_type, ObsType::Image);
    let task = LoadedTask::load_obs(TaskId::Aligning, ObsType::Image).unwrap();
    let mut policy = OnnxPolicy::load(&bytes, &manifest, &task.spec(), 0).unwrap();
    let shape = policy.shape();
    assert_eq!((shape.history, shape.obs_dim, shape.act_dim), (1, 3, 3));

    let set = task.def.context_set().unwrap();
    let mut env = task.env().unwrap();
    env.reset(set.get(0).unwrap()).unwrap();
    let cams = camera::camera_ids(&task.model).unwrap();
    let mut images = Vec::new();
    camera::capture(&mut env.sim.data, &cams, &mut images).unwrap();
    // Row 0: the rendered frame; row 1: a black frame.
    images.resize(2 * camera::OBS_LEN, 0.0);
    let obs = vec![0.5f32; 2 * 3];
    let (ids, steps) = ([0u64, 1], [0u64, 0]);
    let mut q = Query::new(&ids, &steps, &obs);
    q.images = Some(&images);
    let out = policy.infer(&q).unwrap();
    assert_eq!((out.batch, out.act_dim), (2, 3));
    assert!(
        out.data.iter().all(|a| a.is_finite() && a.abs() < 0.05),
        "{:?}",
        out.data
    );
    assert_ne!(
        out.data[0..3],
        out.data[3..6],
        "the actions do not depend on the images"
    );
}
