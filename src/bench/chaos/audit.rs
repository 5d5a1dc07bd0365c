//! What the chaos bench checks once a run has ended: every accepted
//! submission ended as its kind must, none is lost, every completed result
//! equals a plain `d3il eval` of the same policy bit for bit (but for the
//! measured inference time), and no row or file is left behind.

use super::load::{Answer, Endpoint, Kind};
use super::soak::PhaseRun;
use anyhow::Context;
use d3il_protocol::EvalResult;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;
use std::process::Command;

/// Failure kinds that tell a submitter what to change (the model, its
/// actions, its endpoint, its resource use). A crash, an internal error, a
/// bad job or a protocol violation says nothing they can act on.
const ACTIONABLE: [&str; 7] = [
    "bad_model",
    "bad_action",
    "remote",
    "bad_endpoint",
    "memory_limit",
    "cpu_limit",
    "wall_clock",
];

/// The checks of one run.
#[derive(Debug, Default)]
pub struct Verdict {
    /// Acknowledged submissions missing from the database, or not ended.
    pub lost: usize,
    /// Completed results that differ from the plain evaluation.
    pub mismatched: usize,
    /// Failed submissions whose reason the submitter cannot act on.
    pub unactionable: usize,
    /// Outcomes other than the kind's: a good policy failed or refused, a
    /// hostile one completed, a duplicate or a cut-off upload stored.
    pub wrong: usize,
    /// Rows and files left behind.
    pub orphans: usize,
    /// Submissions failed as `crashed` because the injector killed their
    /// worker on every attempt (each kill counts as an attempt, as a crash
    /// does): the faults' doing, reported but not a broken promise.
    pub killed_by_faults: usize,
    /// p99 of submission-to-result of the completed good and remote ones, s.
    pub p99: f64,
    pub problems: Vec<String>,
}

impl Verdict {
    pub fn broken(&self) -> usize {
        self.lost + self.mismatched + self.unactionable + self.wrong + self.orphans
    }

    fn problem(&mut self, counter: fn(&mut Verdict) -> &mut usize, what: String) {
        *counter(self) += 1;
        self.problems.push(what);
    }
}

/// The checks that need no plain evaluation.
fn check(run: &PhaseRun) -> Verdict {
    let mut v = Verdict::default();
    let name = run.name;
    let by_method: HashMap<&str, Vec<&super::soak::SubmissionEnd>> =
        run.submissions.iter().fold(HashMap::new(), |mut m, s| {
            m.entry(s.method.as_str()).or_default().push(s);
            m
        });
    let mut latencies = vec![];
    for s in &run.sent {
        let rows: Vec<_> = by_method
            .get(s.method.as_str())
            .cloned()
            .unwrap_or_default();
        let what = format!(
            "{name} #{} ({}, {}, front end {})",
            s.n,
            s.kind.label(),
            s.method,
            s.front
        );
        match (&s.kind, &s.answer) {
            (Kind::CutOff, _) => {
                if !rows.is_empty() {
                    v.problem(
                        |v| &mut v.wrong,
                        format!("{what}: the cut-off upload was stored"),
                    );
                }
                continue;
            }
            (Kind::Duplicate { .. }, _) => {
                if rows.iter().filter(|r| r.status != "failed").count() > 1 {
                    v.problem(
                        |v| &mut v.wrong,
                        format!("{what}: a second submission of the same seed was accepted"),
                    );
                }
                continue;
            }
            (_, Answer::Accepted(id)) if !rows.iter().any(|r| r.id == *id) => {
                v.problem(
                    |v| &mut v.lost,
                    format!("{what}: accepted as {id}, not in the database"),
                );
                continue;
            }
            (Kind::Good(_) | Kind::Remote, Answer::Refused { status, message }) => {
                v.problem(
                    |v| &mut v.wrong,
                    format!("{what}: refused ({status}): {message}"),
                );
                continue;
            }
            _ => {}
        }
        for r in rows {
            match r.status.as_str() {
                "completed" => {
                    if matches!(s.kind, Kind::Hostile(_)) {
                        v.problem(
                            |v| &mut v.wrong,
                            format!("{what}: the hostile model completed (submission {})", r.id),
                        );
                    }
                    if let Some(end) = run.seen.get(&r.id).and_then(|x| x.ended_at) {
                        latencies.push(end.duration_since(s.at).as_secs_f64());
                    }
                }
                "failed" => {
                    let kind = r.error_kind.clone().unwrap_or_default();
                    let message = r.error_message.clone().unwrap_or_default();
                    let every_attempt_killed = kind == "crashed"
                        && run.jobs.iter().any(|j| {
                            j.submission_id == r.id
                                && j.state == "failed"
                                && run.outside_kills.get(&j.id).copied().unwrap_or(0)
                                    >= j.attempts as usize
                        });
                    if every_attempt_killed {
                        v.killed_by_faults += 1;
                        v.problems.push(format!(
                            "{what}: submission {} failed: the fault injector killed its worker on each of its attempts (not counted as broken)",
                            r.id
                        ));
                    } else if !ACTIONABLE.contains(&kind.as_str()) {
                        v.problem(
                            |v| &mut v.unactionable,
                            format!("{what}: submission {} failed ({kind}): {message}", r.id),
                        );
                    } else if s.kind.policy().is_some() {
                        v.problem(
                            |v| &mut v.wrong,
                            format!("{what}: the good policy failed ({kind}): {message}"),
                        );
                    }
                }
                other => v.problem(
                    |v| &mut v.lost,
                    format!("{what}: submission {} still {other}", r.id),
                ),
            }
        }
    }
    let acknowledged: Vec<i64> = run
        .sent
        .iter()
        .filter_map(|s| match s.answer {
            Answer::Accepted(id) => Some(id),
            _ => None,
        })
        .collect();
    for (id, _) in run
        .seen
        .iter()
        .filter(|(id, s)| s.status == super::soak::VANISHED && !acknowledged.contains(id))
    {
        v.problem(
            |v| &mut v.lost,
            format!("{name}: submission {id} was in the database and is gone"),
        );
    }
    let sent: std::collections::HashSet<&str> =
        run.sent.iter().map(|s| s.method.as_str()).collect();
    for s in run
        .submissions
        .iter()
        .filter(|s| !sent.contains(s.method.as_str()))
    {
        v.problem(
            |v| &mut v.orphans,
            format!(
                "{name}: submission {} of `{}`, which nobody sent",
                s.id, s.method
            ),
        );
    }
    orphans(run, &mut v);
    latencies.sort_by(f64::total_cmp);
    v.p99 = percentile(&latencies, 0.99);
    v
}

/// Rows and files left behind once every submission ended.
fn orphans(run: &PhaseRun, v: &mut Verdict) {
    let name = run.name;
    let status: HashMap<i64, &str> = run
        .submissions
        .iter()
        .map(|s| (s.id, s.status.as_str()))
        .collect();
    for j in &run.jobs {
        let sub = status.get(&j.submission_id).copied().unwrap_or("missing");
        if j.state != "done" && j.state != "failed" {
            v.problem(
                |v| &mut v.orphans,
                format!(
                    "{name}: job {} of submission {} ({sub}) is still {}",
                    j.id, j.submission_id, j.state
                ),
            );
        } else if j.leased {
            v.problem(
                |v| &mut v.orphans,
                format!(
                    "{name}: job {} is {} but still has a lease owner",
                    j.id, j.state
                ),
            );
        }
        if j.has_part {
            v.problem(
                |v| &mut v.orphans,
                format!(
                    "{name}: job {} of {sub} submission {} still holds its shard's part",
                    j.id, j.submission_id
                ),
            );
        }
        if sub == "completed" && j.state != "done" {
            v.problem(
                |v| &mut v.orphans,
                format!(
                    "{name}: job {} of completed submission {} is {}",
                    j.id, j.submission_id, j.state
                ),
            );
        }
    }
    for s in &run.submissions {
        let has_result = run.results.contains(&s.id);
        if (s.status == "completed") != has_result {
            v.problem(
                |v| &mut v.orphans,
                format!(
                    "{name}: submission {} is {} with{} a result row",
                    s.id,
                    s.status,
                    if has_result { "" } else { "out" }
                ),
            );
        }
        if s.status != "completed" && run.rollouts.contains_key(&s.id) {
            v.problem(
                |v| &mut v.orphans,
                format!("{name}: {} submission {} has rollout rows", s.status, s.id),
            );
        }
    }
    for m in &run.lone_methods {
        v.problem(
            |v| &mut v.orphans,
            format!("{name}: method `{m}` has no submission"),
        );
    }
    // Files: no temporary upload, no policy file that no live submission
    // uses, and every live submission's file present.
    let live: std::collections::HashSet<String> = run
        .submissions
        .iter()
        .filter(|s| s.status != "failed")
        .filter_map(|s| s.onnx_path.as_deref())
        .filter_map(|p| {
            Path::new(p)
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
        })
        .collect();
    for f in &run.files {
        if f.contains(d3il_server::ops::TMP_MARKER) {
            v.problem(
                |v| &mut v.orphans,
                format!(
                    "{name}: temporary upload {f} left in {}",
                    run.policies_dir.display()
                ),
            );
        } else if !live.contains(f) {
            v.problem(
                |v| &mut v.orphans,
                format!("{name}: policy file {f} that no live submission uses"),
            );
        }
    }
    for f in live.iter().filter(|f| !run.files.contains(f)) {
        v.problem(
            |v| &mut v.orphans,
            format!("{name}: the policy file {f} of a live submission is missing"),
        );
    }
    for m in &run.exited {
        v.problem(|v| &mut v.orphans, format!("{name}: {m} exited on its own"));
    }
}

/// Nearest-rank percentile of sorted values (0 when there are none).
fn percentile(sorted: &[f64], p: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let rank = ((p * sorted.len() as f64).ceil() as usize).clamp(1, sorted.len());
    sorted[rank - 1]
}

/// Checks every run, then compares each completed good or remote
/// submission with a plain `d3il eval` of its policy and seed (one per
/// policy and seed, shared by the runs).
pub fn compare_with_plain_evals(
    dir: &Path,
    runs: &[&PhaseRun],
    endpoint: &Endpoint,
) -> anyhow::Result<Vec<Verdict>> {
    let mut plain: BTreeMap<(&'static str, u32), EvalResult> = BTreeMap::new();
    let mut verdicts = vec![];
    for run in runs {
        let mut v = check(run);
        let ids: HashMap<&str, Vec<i64>> =
            run.submissions.iter().fold(HashMap::new(), |mut m, s| {
                m.entry(s.method.as_str()).or_default().push(s.id);
                m
            });
        for s in run
            .sent
            .iter()
            .filter(|s| !matches!(s.kind, Kind::Duplicate { .. }))
        {
            let Some(policy) = s.kind.policy() else {
                continue;
            };
            for id in ids.get(s.method.as_str()).into_iter().flatten() {
                let Some(stored) = run.stored.get(id) else {
                    continue;
                };
                let key = (policy, s.seed);
                let reference = match plain.entry(key) {
                    std::collections::btree_map::Entry::Occupied(e) => e.into_mut(),
                    std::collections::btree_map::Entry::Vacant(e) => {
                        e.insert(plain_eval(dir, policy, s.seed, endpoint)?)
                    }
                };
                if let Some(d) = stored.difference_except_timings(reference) {
                    v.problem(
                        |v| &mut v.mismatched,
                        format!("{} #{} ({policy}, seed {}): submission {id} differs from d3il eval: {d}", run.name, s.n, s.seed),
                    );
                }
            }
        }
        verdicts.push(v);
    }
    Ok(verdicts)
}

/// `d3il eval --protocol quick --seed SEED` of `policy` (a fixture stem or
/// `remote`), read back from its `--json`.
fn plain_eval(
    dir: &Path,
    policy: &str,
    seed: u32,
    endpoint: &Endpoint,
) -> anyhow::Result<EvalResult> {
    let json = dir.join(format!("plain-{policy}-{seed}.json"));
    let mut cmd = Command::new(super::exe()?);
    cmd.args([
        "eval",
        "--protocol",
        "quick",
        "--seed",
        &seed.to_string(),
        "--json",
    ])
    .arg(&json);
    if policy == "remote" {
        cmd.args([
            "--task",
            "avoiding",
            "--allow-private-endpoints",
            "--policy",
            &endpoint.url,
        ]);
    } else {
        let task = if policy.starts_with("aligning") {
            "aligning"
        } else {
            "avoiding"
        };
        let onnx = crate::common::assets_dir()
            .join("fixtures")
            .join(format!("{policy}.onnx"));
        cmd.args(["--task", task, "--policy"]).arg(onnx);
    }
    let out = cmd.output().context("running d3il eval")?;
    anyhow::ensure!(
        out.status.success(),
        "the plain d3il eval of {policy} (seed {seed}) failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let text =
        std::fs::read_to_string(&json).with_context(|| format!("reading {}", json.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not a result", json.display()))
}

/// Per run and kind: requests, accepted, refused, unanswered, completed,
/// failed; then the checks.
pub fn table(runs: &[(&str, &PhaseRun, &Verdict)]) -> String {
    let mut out = format!(
        "{:<7} {:<16} {:>5} {:>9} {:>8} {:>10} {:>10} {:>7}\n",
        "run", "kind", "sent", "accepted", "refused", "no answer", "completed", "failed"
    );
    for (name, run, v) in runs {
        let status: HashMap<&str, Vec<&str>> =
            run.submissions.iter().fold(HashMap::new(), |mut m, s| {
                m.entry(s.method.as_str())
                    .or_default()
                    .push(s.status.as_str());
                m
            });
        let mut rows: BTreeMap<&str, [usize; 6]> = BTreeMap::new();
        for s in &run.sent {
            let r = rows.entry(s.kind.label()).or_default();
            r[0] += 1;
            match &s.answer {
                Answer::Accepted(_) => r[1] += 1,
                Answer::Refused { .. } => r[2] += 1,
                Answer::Unanswered(_) | Answer::FrontDown => r[3] += 1,
                Answer::CutOff => {}
            }
            if !matches!(s.kind, Kind::Duplicate { .. }) {
                for st in status.get(s.method.as_str()).into_iter().flatten() {
                    match *st {
                        "completed" => r[4] += 1,
                        "failed" => r[5] += 1,
                        _ => {}
                    }
                }
            }
        }
        for (kind, r) in rows {
            out += &format!(
                "{name:<7} {kind:<16} {:>5} {:>9} {:>8} {:>10} {:>10} {:>7}\n",
                r[0], r[1], r[2], r[3], r[4], r[5]
            );
        }
        let attempts = run.jobs.iter().filter(|j| j.attempts > 1).count();
        out += &format!(
            "{name}: {} shards re-run (a lease taken over or a crash retried), {attempts} with more than one counted attempt; p99 submission-to-result {:.1} s\n",
            run.reruns, v.p99
        );
        out += &format!(
            "{name}: lost {}, mismatched {}, failed without an actionable reason {}, wrong outcome {}, rows or files left behind {}; failed because every attempt's worker was killed by the injector {}\n",
            v.lost, v.mismatched, v.unactionable, v.wrong, v.orphans, v.killed_by_faults
        );
    }
    out
}
