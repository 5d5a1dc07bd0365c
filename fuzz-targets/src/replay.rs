//! The two inputs of `d3il replay` (and of the server's video renders,
//! which run `d3il replay --result`): the first byte picks the input, the
//! rest is the file. Below 128: an episode (`--task T --input ep.json`)
//! for task `byte % 8`; from 128: a result document (`--result out.json
//! --rollout N`) and its rollout `byte - 128`. Both are parsed with
//! [`d3il_evaluator::replay_input`] as the command does, then simulated:
//! the actions and the trace drive MuJoCo, so a value the parser lets
//! through (NaN, huge, a trace of another set) must end in an error with
//! a message, never a panic.

use crate::assert_described;
use d3il_evaluator::open_loop::{replay_actions, OpenLoopOptions};
use d3il_evaluator::replay_input::{Episode, ReplayDoc};
use d3il_evaluator::tasks::LoadedTask;
use d3il_evaluator::trace::{load_task, replay as replay_trace};
use d3il_protocol::TaskId;
use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;

thread_local! {
    /// Loaded tasks by (task, observation type, robot look): loading
    /// compiles the scene, which would dominate every run.
    static TASKS: RefCell<HashMap<String, Rc<LoadedTask>>> = RefCell::new(HashMap::new());
}

fn cached(key: String, load: impl FnOnce() -> Option<LoadedTask>) -> Option<Rc<LoadedTask>> {
    if let Some(t) = TASKS.with(|m| m.borrow().get(&key).cloned()) {
        return Some(t);
    }
    let task = Rc::new(load()?);
    TASKS.with(|m| m.borrow_mut().insert(key, task.clone()));
    Some(task)
}

pub fn replay(data: &[u8]) {
    let Some((&pick, rest)) = data.split_first() else {
        return;
    };
    // `d3il replay` reads its input as UTF-8 text.
    let Ok(text) = std::str::from_utf8(rest) else {
        return;
    };
    if pick < 128 {
        episode(TaskId::ALL[usize::from(pick) % TaskId::ALL.len()], text);
    } else {
        record(usize::from(pick - 128), text);
    }
}

fn episode(task: TaskId, text: &str) {
    let loaded = cached(format!("{task}"), || {
        Some(LoadedTask::load(task).expect("the committed task loads"))
    })
    .expect("loads");
    let ep = match Episode::parse(text, &loaded) {
        Ok(ep) => ep,
        Err(e) => return assert_described("episode", &e),
    };
    match replay_actions(
        &loaded,
        &ep.context,
        &ep.actions,
        OpenLoopOptions::default(),
    ) {
        Ok(run) => {
            // One observation after the reset and one per action taken.
            assert_eq!(run.observations.len(), run.tcp.len());
            assert!(
                run.observations.len() <= ep.actions.len() + 1,
                "{} observations from {} actions",
                run.observations.len(),
                ep.actions.len()
            );
        }
        Err(e) => assert_described("episode replay", &e.source),
    }
}

fn record(number: usize, text: &str) {
    let doc = match ReplayDoc::parse(text) {
        Ok(doc) => doc,
        Err(e) => return assert_described("result document", &e),
    };
    let (record, trace) = match doc.rollout(number) {
        Ok(r) => r,
        Err(e) => return assert_described("rollout lookup", &e),
    };
    let m = &doc.manifest;
    let key = format!("{}/{}/{:?}", m.task, m.obs_type, m.robot_look);
    let mut failed = None;
    let Some(task) = cached(key, || match load_task(m) {
        Ok(t) => Some(t),
        Err(e) => {
            failed = Some(e);
            None
        }
    }) else {
        if let Some(e) = failed {
            assert_described("load task", &e);
        }
        return;
    };
    match replay_trace(&task, m, record, trace, &mut |_| Ok(())) {
        Ok(check) => assert_eq!(check.number, number, "the replay names another rollout"),
        Err(e) => assert_described("trace replay", &e),
    }
}
