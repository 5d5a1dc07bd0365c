//! Robustness results written into a database as a worker would store them
//! (the harness's `finished_pushing`: the store's claim, `save_robustness`
//! and completion), for the tests of
//! the Robustness view and `d3il tables --table robustness`. The documents
//! are assembled by the evaluator's own `robustness::assemble` from
//! synthetic Pushing results (30 initial states × 16 rollouts per level).
#![allow(dead_code)]

use d3il_evaluator::perturb::Suite;
use d3il_protocol::robustness::RobustnessResult;
use d3il_protocol::{ProtocolKind, TaskId};
use d3il_test_support::server::{finished_pushing, with_sqlite_store, Finished};
use d3il_test_support::{pushing_result, SynthRollout};

/// A method's synthetic behaviour: successes per initial state at level 0
/// (of 16), how many it loses at each level of the suite, and how many
/// behaviours its rollouts spread over.
pub struct Synth {
    pub method: &'static str,
    pub base: usize,
    pub loss_per_level: usize,
    pub behaviours: usize,
    /// Store the document as of another suite version (its sha256 changed):
    /// it must never be ranked with the others.
    pub other_version: bool,
    /// The submission's training seed (a method's seeds are aggregated).
    pub training_seed: i64,
}

pub const OTHER_SHA256: &str = "00000000000000000000000000000000000000000000000000000000000000ff";

/// The robustness document of `s` on Pushing's committed suite.
pub fn document(s: &Synth) -> RobustnessResult {
    let suite = Suite::for_task(TaskId::Pushing).expect("Pushing's suite");
    let result = |k: usize| {
        let b = s.behaviours;
        pushing_result(ProtocolKind::Paper, move |c, r| SynthRollout {
            success: r + (c % 2) < k,
            label: (r + c) % b,
            unstable: false,
        })
    };
    let control = result(s.base);
    let levels = suite
        .perturbations()
        .into_iter()
        .map(|p| {
            let k = s.base.saturating_sub(s.loss_per_level * p.level);
            (p, result(k))
        })
        .collect();
    let mut doc = d3il_evaluator::robustness::assemble(&suite, control, levels, 0)
        .expect("assemble the robustness document");
    if s.other_version {
        doc.suite_sha256 = OTHER_SHA256.into();
    }
    doc
}

/// Writes one finished robustness submission per `synths` entry; returns
/// their ids.
pub fn seed(db: &std::path::Path, synths: &[Synth]) -> Vec<i64> {
    let docs: Vec<(&str, i64, RobustnessResult)> = synths
        .iter()
        .map(|s| (s.method, s.training_seed, document(s)))
        .collect();
    seed_documents(db, &docs)
}

/// Writes one finished robustness submission per (method, training seed,
/// document); returns their ids.
pub fn seed_documents(db: &std::path::Path, docs: &[(&str, i64, RobustnessResult)]) -> Vec<i64> {
    with_sqlite_store(db, async |store| {
        let mut ids = vec![];
        for (method, training_seed, doc) in docs {
            let done = Finished::Robustness(doc);
            ids.push(finished_pushing(store, method, *training_seed, done).await);
        }
        ids
    })
}

/// Three methods: a diverse one that loses little, a narrow one that loses
/// much, and one stored under another suite version.
pub fn three() -> [Synth; 3] {
    [
        Synth {
            method: "Diverse",
            base: 12,
            loss_per_level: 1,
            behaviours: 4,
            other_version: false,
            training_seed: 0,
        },
        Synth {
            method: "Narrow",
            base: 14,
            loss_per_level: 4,
            behaviours: 1,
            other_version: false,
            training_seed: 0,
        },
        Synth {
            method: "Older-Suite",
            base: 10,
            loss_per_level: 2,
            behaviours: 2,
            other_version: true,
            training_seed: 0,
        },
    ]
}

/// [`three`] and a second training seed of the diverse method (stored last,
/// so the first three ids are [`three`]'s): the Robustness view and the
/// tables aggregate it with seed 0 into one method row.
pub fn three_and_a_second_seed() -> Vec<Synth> {
    let mut v: Vec<Synth> = three().into_iter().collect();
    v.push(Synth {
        method: "Diverse",
        base: 10,
        loss_per_level: 1,
        behaviours: 3,
        other_version: false,
        training_seed: 1,
    });
    v
}
