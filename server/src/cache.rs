//! In-memory cache of the expensive read path of finished submissions
//!: a stored result never changes, so its results document (up to
//! a few hundred kB with 480 rollouts and their paths) is rendered once and
//! served from memory afterwards, as is the status document of a completed
//! submission, which embeds it; the ETag layer in `app.rs` answers
//! revalidations with 304. The submission page is not cached: it lists the
//! row's other training seeds, which change. Bounded: the oldest entry goes
//! when the cache is full.

use std::collections::{HashMap, VecDeque};
use std::sync::{Arc, Mutex};

/// What is cached for a submission.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Rendered {
    /// `GET /api/v1/submissions/{id}/results` (JSON).
    Results,
    /// `GET /api/v1/submissions/{id}` (JSON) of a completed submission: it
    /// embeds the results document, so polling it rebuilt that each time.
    Submission,
    /// Every rollout's path from the traces (SVG; the submission page and
    /// `/plots/submissions/{id}/paths.svg`): it reads every trace.
    Overlay,
    /// The initial-state map (SVG).
    StartMap,
}

type Key = (Rendered, i64);
/// The bodies, and their keys oldest first.
type Entries = (HashMap<Key, Arc<str>>, VecDeque<Key>);

/// Bodies by (kind, submission id), at most `capacity` of them.
#[derive(Debug)]
pub struct FinishedCache {
    capacity: usize,
    inner: Mutex<Entries>,
    /// Lookups answered from memory, and not (`/metrics`).
    pub hits: prometheus_client::metrics::counter::Counter,
    pub misses: prometheus_client::metrics::counter::Counter,
}

impl FinishedCache {
    pub fn new(capacity: usize) -> FinishedCache {
        FinishedCache {
            capacity: capacity.max(1),
            inner: Mutex::new((HashMap::new(), VecDeque::new())),
            hits: Default::default(),
            misses: Default::default(),
        }
    }

    pub fn get(&self, kind: Rendered, id: i64) -> Option<Arc<str>> {
        let g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let found = g.0.get(&(kind, id)).cloned();
        if found.is_some() {
            self.hits.inc();
        } else {
            self.misses.inc();
        }
        found
    }

    /// Stores `body` (call only for what can no longer change) and returns it.
    pub fn put(&self, kind: Rendered, id: i64, body: String) -> Arc<str> {
        let body: Arc<str> = body.into();
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let (map, order) = &mut *g;
        if map.insert((kind, id), body.clone()).is_none() {
            order.push_back((kind, id));
            while order.len() > self.capacity {
                if let Some(old) = order.pop_front() {
                    map.remove(&old);
                }
            }
        }
        body
    }

    /// Drops what was rendered of `id` (an admin withdrew it or put it
    /// back: its status document says so).
    pub fn forget(&self, kind: Rendered, id: i64) {
        let mut g = self.inner.lock().unwrap_or_else(|e| e.into_inner());
        let (map, order) = &mut *g;
        if map.remove(&(kind, id)).is_some() {
            order.retain(|k| *k != (kind, id));
        }
    }

    pub fn len(&self) -> usize {
        self.inner.lock().unwrap_or_else(|e| e.into_inner()).0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_oldest_entry_goes_first() {
        let c = FinishedCache::new(2);
        c.put(Rendered::Results, 1, "r1".into());
        c.put(Rendered::Results, 2, "r2".into());
        assert_eq!(c.get(Rendered::Results, 1).as_deref(), Some("r1"));
        c.put(Rendered::Results, 3, "r3".into());
        assert_eq!(c.len(), 2);
        assert!(c.get(Rendered::Results, 1).is_none());
        assert_eq!(c.get(Rendered::Results, 3).as_deref(), Some("r3"));
    }
}
