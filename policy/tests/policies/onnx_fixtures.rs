//! The committed ONNX fixtures (scripts/make_fixtures.py) loaded and run with tract.

use crate::common;

use common::{fixture, spec};
use d3il_policy::{
    validate_actions, ActionChunks, OnnxPolicy, Policy, PolicyError, Query, IMAGE_LEN,
};
use d3il_protocol::{ErrorKind, Normalisation, ObsType, TaskId};

fn load(name: &str, task: TaskId, seed: u64) -> Result<OnnxPolicy, PolicyError> {
    let (bytes, man) = fixture(name);
    OnnxPolicy::load(&bytes, &man, &spec(task), seed)
}

fn run(p: &mut OnnxPolicy, ids: &[u64], steps: &[u64], obs: &[f32]) -> ActionChunks {
    let q = Query::new(ids, steps, obs);
    let a = p.infer(&q).expect("inference");
    validate_actions(&q, &p.shape(), &a).expect("valid actions");
    a
}

fn close(a: f32, b: f32) -> bool {
    (a - b).abs() < 1e-6
}

#[test]
fn avoiding_path_steers_towards_the_waypoints() {
    let mut p = load("avoiding_path", TaskId::Avoiding, 0).unwrap();
    let s = p.shape();
    assert_eq!(
        (s.history, s.horizon, s.execute, s.obs_dim, s.act_dim),
        (1, 1, 1, 4, 2)
    );
    // [desired x, desired y, measured x, measured y] (docs/original-d3il.md §10.2.3)
    let obs = [
        0.5249, -0.2797, 0.5249, -0.2797, // start: towards 0.57, clipped to +0.008
        0.565, -0.05, 0.56, -0.06, // phase 1 near the waypoint: 0.57 - 0.565
        0.55, 0.0, 0.55, -0.01, // phase 2, coming from 0.57: towards 0.50, clipped
        0.57, 0.2, 0.56, 0.19, // phase 3, past home 0.50: towards 0.575
    ];
    let a = run(&mut p, &[0, 1, 2, 3], &[0, 10, 40, 60], &obs);
    let want = [0.008, 0.008, 0.005, 0.008, -0.008, 0.008, 0.005, 0.008];
    for (g, w) in a.data.iter().zip(want) {
        assert!(close(*g, w), "{:?} vs {want:?}", a.data);
    }
}

#[test]
fn history_and_chunk_fixture_uses_newest_entry_and_repeats() {
    let mut p = load("avoiding_k5_h3", TaskId::Avoiding, 0).unwrap();
    let s = p.shape();
    assert_eq!((s.history, s.horizon, s.execute), (5, 3, 1));
    // Old entries are garbage; the newest one is the start position.
    let mut obs = vec![9.0f32; 4 * 4];
    obs.extend_from_slice(&[0.5249, -0.2797, 0.5249, -0.2797]);
    let a = run(&mut p, &[7], &[0], &obs);
    assert_eq!((a.batch, a.horizon, a.act_dim), (1, 3, 2));
    for h in 0..3 {
        assert!(close(a.action(0, h)[0], 0.008) && close(a.action(0, h)[1], 0.008));
    }
}

#[test]
fn noise_is_seeded_per_rollout_and_step_and_independent_of_batching() {
    let start = [0.5249f32, -0.2797, 0.5249, -0.2797];
    let ids: Vec<u64> = (0..64).collect();
    let steps = vec![0u64; 64];
    let obs: Vec<f32> = start.iter().copied().cycle().take(4 * 64).collect();

    let mut p = load("avoiding_noise", TaskId::Avoiding, 42).unwrap();
    let a = run(&mut p, &ids, &steps, &obs);
    // At the start the noise sign picks the side: both appear among 64 rollouts.
    let right = (0..64).filter(|&i| close(a.action(i, 0)[0], 0.008)).count();
    let left = (0..64)
        .filter(|&i| close(a.action(i, 0)[0], -0.008))
        .count();
    assert_eq!(right + left, 64);
    assert!(right > 10 && left > 10, "right {right} left {left}");

    // Same seed, fresh policy object, rows queried one at a time in reverse order.
    let mut p2 = load("avoiding_noise", TaskId::Avoiding, 42).unwrap();
    for i in (0..64).rev() {
        let b = run(&mut p2, &[i as u64], &[0], &start);
        assert_eq!(b.data, a.chunk(i), "rollout {i}");
    }
    // Another seed gives another pattern; another step too.
    let mut p3 = load("avoiding_noise", TaskId::Avoiding, 43).unwrap();
    assert_ne!(run(&mut p3, &ids, &steps, &obs).data, a.data);
    let later = vec![1u64; 64];
    assert_ne!(run(&mut p, &ids, &later, &obs).data, a.data);
}

#[test]
fn fixed_batch_model_runs_row_by_row_with_same_results() {
    let mut sym = load("aligning_mlp", TaskId::Aligning, 0).unwrap();
    let mut one = load("aligning_mlp_batch1", TaskId::Aligning, 0).unwrap();
    let obs: Vec<f32> = (0..5 * 20)
        .map(|i| ((i * 37 % 11) as f32 - 5.0) * 0.1)
        .collect();
    let ids = [0, 1, 2, 3, 4];
    let steps = [0; 5];
    let a = run(&mut sym, &ids, &steps, &obs);
    let b = run(&mut one, &ids, &steps, &obs);
    assert_eq!((a.batch, a.horizon, a.act_dim), (5, 1, 3));
    for (x, y) in a.data.iter().zip(&b.data) {
        assert!((x - y).abs() < 1e-5, "{:?} vs {:?}", a.data, b.data);
    }
    // Different rows give different actions (the MLP is not constant).
    assert_ne!(a.chunk(0), a.chunk(1));
    // Empty batch is fine.
    assert_eq!(run(&mut sym, &[], &[], &[]).data.len(), 0);
}

#[test]
fn manifest_normalisation_is_applied() {
    let (bytes, mut man) = fixture("avoiding_path");
    man.normalisation = Some(Normalisation {
        obs_mean: Some(vec![0.0; 4]),
        obs_std: Some(vec![1.0; 4]),
        act_mean: Some(vec![0.001, 0.0]),
        act_std: Some(vec![2.0, 3.0]),
    });
    let mut p = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Avoiding), 0).unwrap();
    let a = run(&mut p, &[0], &[0], &[0.5249, -0.2797, 0.5249, -0.2797]);
    assert!(
        close(a.data[0], 0.008 * 2.0 + 0.001) && close(a.data[1], 0.024),
        "{:?}",
        a.data
    );

    man.normalisation = Some(Normalisation {
        obs_mean: Some(vec![0.0; 3]),
        ..Default::default()
    });
    let e = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Avoiding), 0).unwrap_err();
    assert!(
        e.to_string()
            .contains("normalisation.obs_mean`: has 3 entries but task avoiding needs 4"),
        "{e}"
    );
}

#[test]
fn image_policy_shape_is_accepted_and_runs() {
    let (bytes, man) = fixture("aligning_image");
    assert_eq!(man.obs_type, ObsType::Image);
    let mut p = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Aligning), 0).unwrap();
    let images = vec![0.5f32; 2 * IMAGE_LEN];
    let obs = vec![0.0f32; 2 * 20];
    let q = Query {
        rollout_ids: &[0, 1],
        steps: &[0, 0],
        obs: &obs,
        images: Some(&images),
        window: None,
        prev_actions: None,
    };
    let a = p.infer(&q).unwrap();
    assert!(a.data.iter().all(|&x| close(x, 0.0005)), "{:?}", a.data);
    // The same file declared as a state policy has no `obs` input.
    let mut man2 = man.clone();
    man2.obs_type = ObsType::State;
    let e = OnnxPolicy::load(&bytes, &man2, &spec(TaskId::Aligning), 0).unwrap_err();
    assert!(e.to_string().contains("input `images`"), "{e}");
}

/// The paper-sized image network gives a row the same actions alone as in a
/// batch split across threads (agent_fixtures.rs has the same check for every
/// state method family): one-row calls are padded to two rows, since tract's
/// one-row convolution and matrix kernels round differently.
#[test]
fn an_image_rows_actions_do_not_depend_on_its_company() {
    let (bytes, man) = fixture("aligning_resnet18");
    let mut sp = spec(TaskId::Aligning);
    sp.obs_dim = 3; // the image variant's low-dimensional input (docs/images.md)
    let mut p = OnnxPolicy::load(&bytes, &man, &sp, 0).unwrap();
    let image = |r: usize| -> Vec<f32> {
        (0..IMAGE_LEN)
            .map(|i| (((i + r * 977) as f32 * 0.0137).sin() + 1.0) / 2.0)
            .collect()
    };
    let run = |p: &mut OnnxPolicy, b: usize| -> Vec<f32> {
        let ids: Vec<u64> = (0..b as u64).collect();
        let steps = vec![0u64; b];
        let images: Vec<f32> = (0..b).flat_map(|r| image(b - 1 - r)).collect();
        let obs: Vec<f32> = (0..b * 3)
            .map(|i| 0.1 * ((b * 3 - 1 - i) % 3) as f32)
            .collect();
        let q = Query {
            rollout_ids: &ids,
            steps: &steps,
            obs: &obs,
            images: Some(&images),
            window: None,
            prev_actions: None,
        };
        p.infer(&q).unwrap().chunk(b - 1).to_vec()
    };
    p.set_threads(1);
    let alone = run(&mut p, 1);
    for (threads, b) in [(1, 1), (1, 2), (2, 3), (2, 5)] {
        p.set_threads(threads);
        let got = run(&mut p, b);
        assert!(
            got.iter()
                .zip(&alone)
                .all(|(x, y)| x.to_bits() == y.to_bits()),
            "last row of {b} on {threads} threads: {got:?}, alone {alone:?}"
        );
    }
}

#[test]
fn manifest_and_task_mismatches_are_explained() {
    let (bytes, mut man) = fixture("avoiding_path");
    let e = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Aligning), 0).unwrap_err();
    assert!(
        e.to_string()
            .contains("for task avoiding but is being evaluated on aligning"),
        "{e}"
    );
    man.horizon = 3;
    let e = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Avoiding), 0).unwrap_err();
    assert!(e.to_string().contains("manifest says horizon H = 3"), "{e}");
    man.horizon = 1;
    man.execute = 2;
    let e = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Avoiding), 0).unwrap_err();
    assert!(e.to_string().contains("execute E = 2"), "{e}");
    man.execute = 1;
    man.history = 5;
    // The fixture fixes k = 1 in its input shape.
    let e = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Avoiding), 0).unwrap_err();
    assert!(
        e.to_string()
            .contains("history dimension 1 but the manifest says history k = 5"),
        "{e}"
    );
    assert_eq!(e.kind(), ErrorKind::BadModel);
}

fn hostile(name: &str) -> PolicyError {
    let e = load(name, TaskId::Avoiding, 0).expect_err(name);
    assert_eq!(e.kind(), ErrorKind::BadModel, "{name}: {e}");
    e
}

#[test]
fn truncated_and_garbage_files_are_rejected() {
    for name in ["hostile_truncated", "hostile_garbage"] {
        let e = hostile(name);
        assert!(e.to_string().contains("could not be parsed"), "{name}: {e}");
    }
    let e =
        OnnxPolicy::load(b"", &fixture("avoiding_path").1, &spec(TaskId::Avoiding), 0).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::BadModel, "{e}");
}

#[test]
fn huge_declared_initializers_are_refused_before_allocation() {
    let e = hostile("hostile_huge_initializer").to_string();
    assert!(
        e.contains("`huge_weight` declares shape 100000x100000 (37.3 GiB) but holds 16 bytes"),
        "{e}"
    );
    let e = hostile("hostile_external_data").to_string();
    assert!(e.contains("external file"), "{e}");
}

#[test]
fn wrong_dimensions_name_what_was_expected() {
    let e = hostile("hostile_wrong_obs_dim").to_string();
    assert!(
        e.contains(
            "input `obs` has last dimension 3 but task avoiding expects 4 (previous command xy + observation xy)"
        ),
        "{e}"
    );
    let e = hostile("hostile_wrong_act_dim").to_string();
    assert!(
        e.contains("has last dimension 3 but task avoiding expects 2 (xy delta"),
        "{e}"
    );
}

#[test]
fn a_graph_that_mixes_the_rows_of_the_batch_is_refused() {
    let (bytes, man) = fixture("hostile_mixes_rows");
    // It loads; the test inference every admission and evaluation runs finds it.
    let p = OnnxPolicy::load(&bytes, &man, &spec(TaskId::Avoiding), 0).unwrap();
    let e = p.test_inference().unwrap_err();
    assert_eq!(e.kind(), ErrorKind::BadModel, "{e}");
    let m = e.to_string();
    assert!(
        m.contains("the graph mixes the rows of the batch") && m.contains("model.eval()"),
        "{m}"
    );
}

#[test]
fn random_operators_in_the_graph_are_refused() {
    let e = hostile("hostile_random_op").to_string();
    assert!(
        e.contains("is a RandomNormalLike operator")
            && e.contains("not be reproducible")
            && e.contains("`noise` input"),
        "{e}"
    );
}

#[test]
fn nan_output_is_caught_by_validation() {
    let mut p = load("hostile_nan", TaskId::Avoiding, 0).unwrap();
    let ids = [3, 9];
    let steps = [12, 12];
    let obs = [0.5f32; 8];
    let q = Query::new(&ids, &steps, &obs);
    let a = p.infer(&q).unwrap();
    let e = validate_actions(&q, &p.shape(), &a).unwrap_err();
    assert_eq!(e.kind(), ErrorKind::BadAction);
    let m = e.to_string();
    assert!(
        m.contains("NaN") && m.contains("rollout 3") && m.contains("step 12"),
        "{m}"
    );
}

#[test]
fn endless_graph_loads_without_running() {
    // Loading must not execute (or constant-fold) the compute chain; running it
    // is stopped by the worker's wall-clock limit, not by the policy.
    let p = load("hostile_endless", TaskId::Avoiding, 0).unwrap();
    assert_eq!(p.shape().act_dim, 2);
}

/// scripts/make_frozen_window_fixture.py: `int(obs.size()[1] / 1)` frozen by
/// tracing into a Reshape to the example window. tract's refusal of the graph
/// with a symbolic window names that cause and its fix, not only tract's nodes.
#[test]
fn a_window_frozen_by_tracing_is_refused_naming_the_cause() {
    let (bytes, man) = fixture("frozen_window");
    let e = d3il_policy::onnx::admit(&bytes, &man, &spec(TaskId::Aligning), 0).unwrap_err();
    let m = e.to_string();
    eprintln!("{m}");
    for want in [
        "int(x.size()[1] / 2)",
        "frozen by tracing",
        "d3il_client.agents",
        "noise[:, i, :T]",
        "docs/export.md",
        "Traps",
    ] {
        assert!(m.contains(want), "`{want}` missing from: {m}");
    }
}
