//! (a) The episodes recorded in the original (`reference-rollouts/`,
//! format in its README) replayed open-loop here: the free-motion TCP
//! error, how long the contact phase stays with the original against how
//! long a one-ulp change of the initial state stays with our own replay
//! (docs/original-d3il.md §01.7.10: contact is chaotic), and the outcome.

use super::{actions, dist, read_json, rows, FidelityError};
use crate::open_loop::{replay_actions, OpenLoopOptions, OpenLoopRun};
use crate::tasks::LoadedTask;
use d3il_protocol::fidelity::{ContactPhase, EpisodeFidelity, EpisodesSection};
use d3il_protocol::TaskId;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A reference object has moved (contact has begun) past this xy distance
/// from its start (m); the free-motion checks of tests/cli/replay_cli.rs use it.
pub const CONTACT_MOTION_M: f64 = 1e-5;
/// Two runs are together while every TCP and object position is this
/// close (m): the scale at which docs/original-d3il.md §01.7.10 watched a
/// 1e-16 difference stay for about 40 steps of pushing, 20 times the
/// free-motion TCP error of the recorded episodes here (about 5e-9 m).
pub const TOGETHER_M: f64 = 1e-7;

/// Every `<task>/<case>.json` under `dir`, sorted.
fn episode_files(dir: &Path) -> Result<Vec<PathBuf>, FidelityError> {
    let mut files = vec![];
    let entries = std::fs::read_dir(dir).map_err(|e| FidelityError::data(dir, e))?;
    for task_dir in entries.flatten().map(|e| e.path()).filter(|p| p.is_dir()) {
        let inner = std::fs::read_dir(&task_dir).map_err(|e| FidelityError::data(&task_dir, e))?;
        files.extend(
            inner
                .flatten()
                .map(|e| e.path())
                .filter(|p| p.extension().is_some_and(|x| x == "json")),
        );
    }
    files.sort();
    if files.is_empty() {
        return Err(FidelityError::data(
            dir,
            "no recorded episodes (<task>/<case>.json)",
        ));
    }
    Ok(files)
}

pub fn section(dir: &Path) -> Result<EpisodesSection, FidelityError> {
    let files = episode_files(dir)?;
    let episodes = files
        .par_iter()
        .map(|f| episode(dir, f))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(EpisodesSection {
        contact_motion_m: CONTACT_MOTION_M,
        together_m: TOGETHER_M,
        episodes,
    })
}

/// An object's name, the reference's path of it and ours.
type PairedPath<'a> = (&'a str, Vec<Vec<f64>>, &'a Vec<[f64; 3]>);

/// Object paths of a run under the reference's names (`push_box (red)` is
/// our `push_box`): only the objects both record.
fn paired_objects<'a>(
    reference: &BTreeMap<String, Vec<Vec<f64>>>,
    run: &'a OpenLoopRun,
) -> Vec<PairedPath<'a>> {
    reference
        .iter()
        .filter_map(|(k, path)| {
            let ours = k.split(" (").next().unwrap_or(k);
            run.objects
                .get_key_value(ours)
                .map(|(name, p)| (name.as_str(), path.clone(), p))
        })
        .collect()
}

/// Distance between two states of the runs (TCP and every paired object).
fn gap(
    a: &OpenLoopRun,
    b_tcp: &[f64],
    b_objects: &[Vec<f64>],
    a_objects: &[&[f64; 3]],
    t: usize,
) -> f64 {
    let mut d = dist(&a.tcp[t], b_tcp);
    for (x, y) in a_objects.iter().zip(b_objects) {
        d = d.max(dist(&x[..], y));
    }
    d
}

fn episode(root: &Path, path: &Path) -> Result<EpisodeFidelity, FidelityError> {
    let r = read_json(path)?;
    let task_name = r["task"].as_str().unwrap_or_default().replace('_', "-");
    let task: TaskId = task_name
        .parse()
        .map_err(|_| FidelityError::data(path, format!("unknown task `{task_name}`")))?;
    let loaded = LoadedTask::load(task)?;
    let acts = actions(&r["policy_actions"], path, "policy_actions")?;
    let rel = path
        .strip_prefix(root)
        .unwrap_or(path)
        .to_string_lossy()
        .into_owned();
    let run = |nudge| {
        replay_actions(
            &loaded,
            &r["context"],
            &acts,
            OpenLoopOptions {
                nudge_one_ulp: nudge,
            },
        )
        .map_err(|source| FidelityError::Replay {
            what: rel.clone(),
            source,
        })
    };
    let (ours, nudged) = (run(false)?, run(true)?);
    let ref_tcp = rows(&r["ee_pos"], path, "ee_pos")?;
    let mut ref_objects = BTreeMap::new();
    if let Some(objs) = r["objects"].as_object() {
        for (k, v) in objs {
            ref_objects.insert(k.clone(), rows(&v["pos"], path, "objects.pos")?);
        }
    }
    let pairs = paired_objects(&ref_objects, &ours);
    let n = ours.tcp.len().min(ref_tcp.len());
    // The first state at which a reference object has moved.
    let moved = pairs
        .iter()
        .filter_map(|(_, p, _)| {
            p.iter()
                .position(|q| (q[0] - p[0][0]).hypot(q[1] - p[0][1]) > CONTACT_MOTION_M)
        })
        .min();
    let free = moved.unwrap_or(n).min(n);
    let free_motion_tcp_max_m = (0..free)
        .map(|t| dist(&ours.tcp[t], &ref_tcp[t]))
        .fold(0.0, f64::max);
    let contact = moved.filter(|&c| c < n).map(|c| {
        let objects_at =
            |t: usize| -> Vec<&[f64; 3]> { pairs.iter().map(|(_, _, p)| &p[t]).collect() };
        let with_original = (c..n).find(|&t| {
            let theirs: Vec<Vec<f64>> = pairs.iter().map(|(_, p, _)| p[t].clone()).collect();
            gap(&ours, &ref_tcp[t], &theirs, &objects_at(t), t) > TOGETHER_M
        });
        let m = n.min(nudged.tcp.len());
        let nudged_objects: Vec<&Vec<[f64; 3]>> = pairs
            .iter()
            .map(|(name, _, _)| &nudged.objects[*name])
            .collect();
        let one_ulp = (c..m).find(|&t| {
            let theirs: Vec<Vec<f64>> = nudged_objects.iter().map(|p| p[t].to_vec()).collect();
            gap(&ours, &nudged.tcp[t], &theirs, &objects_at(t), t) > TOGETHER_M
        });
        let final_object_xy_m = pairs
            .iter()
            .map(|(_, p, q)| {
                let (a, b) = (p.last().expect("rows"), q.last().expect("rows"));
                (a[0] - b[0]).hypot(a[1] - b[1])
            })
            .fold(0.0, f64::max);
        ContactPhase {
            starts_at: c,
            with_original: with_original.map(|t| t - c),
            one_ulp: one_ulp.map(|t| t - c),
            remaining: n - 1 - c,
            final_object_xy_m,
        }
    });
    Ok(EpisodeFidelity {
        task: task.to_string(),
        file: rel,
        description: r["description"].as_str().unwrap_or_default().to_string(),
        steps_original: r["n_steps"].as_u64().unwrap_or(0) as usize,
        steps_here: ours.steps,
        success_original: r["success"].as_bool().unwrap_or(false),
        success_here: ours.success,
        behaviour_original: r["mode"].clone(),
        behaviour_here: ours.behaviour,
        free_motion_steps: free.saturating_sub(1),
        free_motion_tcp_max_m,
        contact,
    })
}
