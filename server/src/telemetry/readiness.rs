//! `/readyz`: ready to take traffic when the database answers, the drift
//! canary passed (or is switched off with `--no-verify`) and some worker
//! slot of this process or some worker host is alive to run what is
//! submitted. Otherwise 503, with a body naming what is not ready.

use crate::canary::CanaryState;
use serde::Serialize;

/// What readiness is decided from.
pub struct Parts {
    /// Err: why the database did not answer.
    pub database: Result<(), String>,
    pub canary: CanaryState,
    /// Worker slots this process was started with (`--workers`; the pool
    /// adds one for quick jobs when it has any).
    pub configured_slots: usize,
    /// Slots whose loop runs.
    pub slots_alive: usize,
    /// Worker hosts connected to the (PostgreSQL) queue.
    pub worker_hosts: usize,
}

/// One check: whether it passes, and what it saw.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Check {
    pub ok: bool,
    pub detail: String,
}

/// The body of `/readyz`.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Report {
    pub ready: bool,
    /// The checks that failed, by name (empty when ready).
    pub not_ready: Vec<&'static str>,
    pub database: Check,
    pub canary: Check,
    pub workers: Check,
}

impl Report {
    pub fn from_parts(p: Parts) -> Report {
        let database = match p.database {
            Ok(()) => Check {
                ok: true,
                detail: "the database answers".into(),
            },
            Err(e) => Check {
                ok: false,
                detail: e,
            },
        };
        let canary = Check {
            ok: matches!(
                p.canary,
                CanaryState::Passed { .. } | CanaryState::Off | CanaryState::Given { .. }
            ),
            detail: p.canary.summary(),
        };
        // The pool runs `workers` general slots plus one for quick jobs.
        let expected = if p.configured_slots > 0 {
            p.configured_slots + 1
        } else {
            0
        };
        let local_ok = expected > 0 && p.slots_alive >= expected;
        let workers = Check {
            ok: local_ok || p.worker_hosts > 0,
            detail: format!(
                "{} of {expected} worker slot(s) of this process alive, {} worker host(s) connected",
                p.slots_alive, p.worker_hosts
            ),
        };
        let mut not_ready = vec![];
        for (name, c) in [
            ("database", &database),
            ("canary", &canary),
            ("workers", &workers),
        ] {
            if !c.ok {
                not_ready.push(name);
            }
        }
        Report {
            ready: not_ready.is_empty(),
            not_ready,
            database,
            canary,
            workers,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parts() -> Parts {
        Parts {
            database: Ok(()),
            canary: CanaryState::Passed {
                fingerprint: "abc".into(),
            },
            configured_slots: 2,
            slots_alive: 3,
            worker_hosts: 0,
        }
    }

    #[test]
    fn readiness_names_each_check_that_fails() {
        assert!(Report::from_parts(parts()).ready);
        let r = Report::from_parts(Parts {
            database: Err("connection refused".into()),
            ..parts()
        });
        assert_eq!(r.not_ready, ["database"]);
        assert_eq!(r.database.detail, "connection refused");
        for (canary, ok) in [
            (CanaryState::Off, true),
            (CanaryState::Running, false),
            (
                CanaryState::Failed {
                    message: "no verify".into(),
                },
                false,
            ),
            (
                CanaryState::Drifted {
                    fingerprint: "x".into(),
                    differences: vec!["aligning: step 3".into()],
                },
                false,
            ),
        ] {
            let r = Report::from_parts(Parts {
                canary: canary.clone(),
                ..parts()
            });
            assert_eq!(r.ready, ok, "{canary:?}");
            assert_eq!(r.not_ready.contains(&"canary"), !ok);
        }
    }

    #[test]
    fn workers_are_local_slots_all_alive_or_a_connected_host() {
        let dead_slot = Parts {
            slots_alive: 2,
            ..parts()
        };
        assert_eq!(Report::from_parts(dead_slot).not_ready, ["workers"]);
        let front_end = Parts {
            configured_slots: 0,
            slots_alive: 0,
            worker_hosts: 0,
            ..parts()
        };
        assert_eq!(Report::from_parts(front_end).not_ready, ["workers"]);
        let with_host = Parts {
            configured_slots: 0,
            slots_alive: 0,
            worker_hosts: 1,
            ..parts()
        };
        assert!(Report::from_parts(with_host).ready);
    }
}
