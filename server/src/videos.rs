//! Rollout videos, made on demand. DESIGN.md: what a policy did is
//! kept as a record, and videos are made "by replaying the record in a
//! process that has the simulator ..., never by the server itself, and
//! cached". So the server writes a replay document (`{"manifest", "rollouts":
//! [the record with its trace]}`) and runs `d3il replay --result DOC
//! --rollout N --video OUT` (the executable of [`VideoConfig`]).
//!
//! Renders run in a pool of their own (a semaphore of `renders` slots,
//! default 1), apart from the evaluation workers, so viewers never starve
//! evaluations; concurrent requests for the same video share one render;
//! at most `max_waiting` distinct videos wait for a slot (then: busy).
//! Videos are cached on disk as `<dir>/<submission>-<N>-<build>.mp4`, where
//! the build is this binary's version and the result's MJCF hash, so another
//! build or scene renders anew; a render writes into a temporary directory
//! and its file is renamed into place when complete.

use crate::config::VideoConfig;
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use tokio::sync::{OnceCell, Semaphore};

/// A video that could not be had.
#[derive(Debug, Clone, thiserror::Error)]
pub enum VideoError {
    /// The replay refused or failed; its own words (e.g. that the record
    /// does not replay, naming the step), or that it took too long.
    #[error("the video could not be made: {0}")]
    Refused(String),
    /// Our side broke (the executable does not start, the disk refuses):
    /// for the operator's log, not the viewer.
    #[error("rendering videos failed: {0}")]
    Broken(String),
    /// Too many distinct videos are waiting for a render slot.
    #[error("{0} videos are waiting to be rendered; try again in a minute")]
    Busy(usize),
}

/// One video to make.
#[derive(Debug, Clone)]
pub struct VideoJob {
    pub submission_id: i64,
    /// The rollout number ([`d3il_protocol::RolloutRecord::number`]).
    pub number: usize,
    /// The replay document, JSON.
    pub document: String,
    /// The result manifest's `mjcf_sha256`.
    pub mjcf_sha256: String,
}

/// A render's outcome, shared by every request that waited for it.
type Shared = Arc<OnceCell<Result<PathBuf, VideoError>>>;

/// The render pool and its cache.
#[derive(Debug)]
pub struct Videos {
    cfg: VideoConfig,
    dir: PathBuf,
    assets_dir: PathBuf,
    slots: Arc<Semaphore>,
    waiting: Mutex<HashMap<String, Shared>>,
    started: AtomicUsize,
    /// Renders and cache hits (`/metrics`).
    pub counters: VideoCounters,
}

/// What the video pool counts.
#[derive(Debug, Default)]
pub struct VideoCounters {
    /// Renders that made a video.
    pub rendered: prometheus_client::metrics::counter::Counter,
    /// Renders that failed.
    pub failed: prometheus_client::metrics::counter::Counter,
    /// Videos served from the cache without a render.
    pub cache_hits: prometheus_client::metrics::counter::Counter,
}

/// Prefix of a render's temporary directory (left by a crash: removed at start).
const TMP_PREFIX: &str = ".render-";

/// The longest replay message passed on (its end: where it says why).
const MAX_MESSAGE: usize = 2000;

impl Videos {
    /// The pool, caching in `cfg.dir` or else `<data_dir>/videos` (created;
    /// temporary files of an earlier run are removed).
    pub fn new(
        cfg: VideoConfig,
        data_dir: &Path,
        assets_dir: &Path,
    ) -> Result<Videos, std::io::Error> {
        let dir = cfg.dir.clone().unwrap_or_else(|| data_dir.join("videos"));
        std::fs::create_dir_all(&dir)?;
        for e in std::fs::read_dir(&dir)?.flatten() {
            if e.file_name().to_string_lossy().starts_with(TMP_PREFIX) {
                let _ = std::fs::remove_dir_all(e.path());
            }
        }
        Ok(Videos {
            slots: Arc::new(Semaphore::new(cfg.renders.max(1))),
            cfg,
            dir,
            assets_dir: assets_dir.to_path_buf(),
            waiting: Mutex::default(),
            started: AtomicUsize::new(0),
            counters: VideoCounters::default(),
        })
    }

    /// Where videos are kept.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Replay processes started since the server started (cache hits and
    /// requests that joined a running render start none).
    pub fn renders_started(&self) -> usize {
        self.started.load(Ordering::SeqCst)
    }

    /// Removes the cached videos of a submission whose result was replaced
    /// (a zoo cell loaded again, `crate::zoo`): they showed the old rollouts.
    pub fn forget(&self, submission_id: i64) {
        let prefix = format!("{submission_id}-");
        let Ok(entries) = std::fs::read_dir(&self.dir) else {
            return;
        };
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if name.starts_with(&prefix) && name.ends_with(".mp4") {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }

    /// The cache file of `job`.
    pub fn path_of(&self, job: &VideoJob) -> PathBuf {
        let scene: String = job
            .mjcf_sha256
            .chars()
            .filter(char::is_ascii_alphanumeric)
            .take(16)
            .collect();
        self.dir.join(format!(
            "{}-{}-{}-{}.mp4",
            job.submission_id,
            job.number,
            env!("CARGO_PKG_VERSION"),
            if scene.is_empty() { "unknown" } else { &scene }
        ))
    }

    /// The video of `job`: from the cache, or rendered (joining a render of
    /// the same video already under way).
    pub async fn video(self: &Arc<Self>, job: VideoJob) -> Result<PathBuf, VideoError> {
        let path = self.path_of(&job);
        if tokio::fs::try_exists(&path).await.unwrap_or(false) {
            self.counters.cache_hits.inc();
            return Ok(path);
        }
        let key = path.to_string_lossy().into_owned();
        let cell = {
            let mut w = self.waiting.lock().unwrap_or_else(|e| e.into_inner());
            match w.get(&key) {
                Some(c) => c.clone(),
                None => {
                    let limit = self.cfg.max_waiting + self.cfg.renders.max(1);
                    if w.len() >= limit {
                        return Err(VideoError::Busy(w.len()));
                    }
                    let c = Shared::default();
                    w.insert(key.clone(), c.clone());
                    c
                }
            }
        };
        let out = cell
            .get_or_init(|| {
                // On a task of its own: a viewer who leaves does not stop
                // the render others wait for (or its caching).
                let me = self.clone();
                let path = path.clone();
                async move {
                    tokio::spawn(async move { me.render(job, path).await })
                        .await
                        .unwrap_or_else(|e| {
                            Err(VideoError::Broken(format!("the render stopped: {e}")))
                        })
                }
            })
            .await
            .clone();
        let mut w = self.waiting.lock().unwrap_or_else(|e| e.into_inner());
        if w.get(&key).is_some_and(|c| Arc::ptr_eq(c, &cell)) {
            w.remove(&key);
        }
        out
    }

    async fn render(&self, job: VideoJob, path: PathBuf) -> Result<PathBuf, VideoError> {
        let _slot = self
            .slots
            .acquire()
            .await
            .map_err(|_| VideoError::Broken("the render pool is closed".into()))?;
        // A render that began before this one waited may have made it.
        if tokio::fs::try_exists(&path).await.unwrap_or(false) {
            return Ok(path);
        }
        static SEQ: AtomicUsize = AtomicUsize::new(0);
        let tmp = self.dir.join(format!(
            "{TMP_PREFIX}{}-{}-{}-{}",
            job.submission_id,
            job.number,
            std::process::id(),
            SEQ.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = tokio::fs::remove_dir_all(&tmp).await;
        let io = |what: &str, e: std::io::Error| {
            VideoError::Broken(format!("{what} {}: {e}", tmp.display()))
        };
        tokio::fs::create_dir_all(&tmp)
            .await
            .map_err(|e| io("cannot create", e))?;
        let out = self.run(&job, &tmp).await;
        match &out {
            Ok(_) => self.counters.rendered.inc(),
            Err(_) => self.counters.failed.inc(),
        };
        let out = match out {
            Ok(video) => tokio::fs::rename(&video, &path)
                .await
                .map(|()| path)
                .map_err(|e| io("cannot move the video out of", e)),
            Err(e) => Err(e),
        };
        let _ = tokio::fs::remove_dir_all(&tmp).await;
        out
    }

    /// Runs the replay in `tmp`; the video it wrote.
    async fn run(&self, job: &VideoJob, tmp: &Path) -> Result<PathBuf, VideoError> {
        let doc = tmp.join("replay.json");
        let video = tmp.join("video.mp4");
        tokio::fs::write(&doc, &job.document)
            .await
            .map_err(|e| VideoError::Broken(format!("cannot write {}: {e}", doc.display())))?;
        self.started.fetch_add(1, Ordering::SeqCst);
        let mut cmd = tokio::process::Command::new(&self.cfg.exe);
        cmd.args(&self.cfg.args)
            .arg("--result")
            .arg(&doc)
            .arg("--rollout")
            .arg(job.number.to_string())
            .arg("--video")
            .arg(&video)
            .env("D3IL_ASSETS", &self.assets_dir)
            // Its message is for viewers: no backtrace after it.
            .env("RUST_BACKTRACE", "0")
            .env("RUST_LIB_BACKTRACE", "0")
            .current_dir(tmp)
            .stdin(std::process::Stdio::null())
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .kill_on_drop(true);
        let child = cmd.spawn().map_err(|e| {
            VideoError::Broken(format!(
                "cannot start the replay ({}): {e}",
                self.cfg.exe.display()
            ))
        })?;
        let done = tokio::time::timeout(self.cfg.timeout, child.wait_with_output()).await;
        let output = match done {
            Err(_) => {
                return Err(VideoError::Refused(format!(
                    "the replay took longer than {} s and was stopped",
                    self.cfg.timeout.as_secs()
                )))
            }
            Ok(Err(e)) => return Err(VideoError::Broken(format!("the replay failed: {e}"))),
            Ok(Ok(o)) => o,
        };
        if !output.status.success() {
            return Err(VideoError::Refused(replay_message(
                &output.stderr,
                output.status,
            )));
        }
        match tokio::fs::metadata(&video).await {
            Ok(m) if m.len() > 0 => Ok(video),
            _ => Err(VideoError::Refused(
                "the replay exited successfully but wrote no video".into(),
            )),
        }
    }
}

/// What a failed replay said (its stderr, without anyhow's `Error: `
/// prefix, the end kept when long), or how it ended when it said nothing.
fn replay_message(stderr: &[u8], status: std::process::ExitStatus) -> String {
    let text = String::from_utf8_lossy(stderr);
    let text = text.trim();
    let text = text.strip_prefix("Error: ").unwrap_or(text);
    let text = text
        .split("\nStack backtrace:")
        .next()
        .unwrap_or(text)
        .trim();
    if text.is_empty() {
        return format!("the replay ended with {status} and gave no reason");
    }
    if text.len() <= MAX_MESSAGE {
        return text.to_string();
    }
    let mut start = text.len() - MAX_MESSAGE;
    while !text.is_char_boundary(start) {
        start += 1;
    }
    format!("…{}", &text[start..])
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::process::ExitStatusExt;

    #[test]
    fn replay_messages_lose_the_prefix_and_keep_the_end() {
        let ok = std::process::ExitStatus::from_raw(1 << 8);
        assert_eq!(
            replay_message(b"Error: step 17 differs\n", ok),
            "step 17 differs"
        );
        assert!(replay_message(b"  ", ok).contains("gave no reason"));
        assert_eq!(
            replay_message(b"Error: no\n\nStack backtrace:\n   0: main\n", ok),
            "no"
        );
        let long = format!("{}the end", "x".repeat(5000));
        let m = replay_message(long.as_bytes(), ok);
        assert!(m.ends_with("the end") && m.chars().count() <= MAX_MESSAGE + 1);
    }
}
