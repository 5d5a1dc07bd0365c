//! What a worker does with one job: build the policy it names, then
//! evaluate it ([`crate::eval`]) or one shard of it.

use crate::eval::race::{self, Contender, RaceOptions, RaceProgress, RaceReport};
use crate::eval::{
    evaluate, protocol_size, sha256_hex, EvalError, EvalOptions, EvalRun, PolicyInfo,
};
use crate::scripted::ScriptedPolicy;
use crate::suite_shard::SuiteRun;
use crate::tasks::{LoadedTask, TaskError};
use d3il_policy::{OnnxPolicy, Policy, RemotePolicy};
use d3il_protocol::{
    race::RaceJob, ErrorKind, EvalResult, Evaluated, Job, JobKind, ObsType, PolicySource, Progress,
    WorkerError,
};

/// Builds the policy a job names. ONNX bytes are checked against the job's sha256.
pub fn load_policy(
    job: &Job,
    task: &LoadedTask,
) -> Result<(Box<dyn Policy>, PolicyInfo), EvalError> {
    let spec = task.spec();
    if job.manifest.task != job.task {
        return Err(EvalError::Setup(format!(
            "the manifest says task `{}` but the job is for `{}`; submit the policy for the task it was trained on",
            job.manifest.task, job.task
        )));
    }
    if job.manifest.obs_type != task.obs_type {
        return Err(EvalError::Setup(format!(
            "the manifest says observation type `{}` but the task was loaded for `{}`",
            job.manifest.obs_type, task.obs_type
        )));
    }
    match &job.policy {
        PolicySource::Onnx { path, sha256 } => {
            let bytes = std::fs::read(path).map_err(|e| {
                EvalError::Setup(format!("cannot read the ONNX file `{path}`: {e}"))
            })?;
            let got = sha256_hex(&bytes);
            if !sha256.is_empty() && &got != sha256 {
                return Err(EvalError::Setup(format!(
                    "the ONNX file's sha256 is {got}, but the job expects {sha256}"
                )));
            }
            let p = OnnxPolicy::load(&bytes, &job.manifest, &spec, job.seed)?;
            Ok((
                Box::new(p),
                PolicyInfo {
                    sha256: got,
                    obs_type: job.manifest.obs_type,
                },
            ))
        }
        PolicySource::Remote { url, secret } => {
            let p = RemotePolicy::connect(
                url,
                secret.as_ref(),
                &spec,
                job.manifest.obs_type,
                job.seed,
                &job.limits,
            )?;
            Ok((
                Box::new(p),
                PolicyInfo {
                    sha256: sha256_hex(url.as_bytes()),
                    obs_type: job.manifest.obs_type,
                },
            ))
        }
        PolicySource::Scripted { name } => {
            let p = ScriptedPolicy::from_name(name, spec)
                .map_err(|e| EvalError::Setup(e.to_string()))?;
            Ok((
                Box::new(p),
                PolicyInfo {
                    sha256: sha256_hex(name.as_bytes()),
                    obs_type: ObsType::State,
                },
            ))
        }
    }
}

/// Everything a worker does for one job (called by `d3il worker` after it has
/// confined itself): load the task and the policy, evaluate, report.
pub fn run_job(
    job: &Job,
    on_progress: &mut dyn FnMut(usize, usize),
) -> Result<EvalResult, WorkerError> {
    let mut counts = |p: &Progress| on_progress(p.rollouts_done, p.rollouts_total);
    match run_job_or_shard(job, &mut counts)? {
        Evaluated::Result(r) => Ok(*r),
        Evaluated::Part(_) => Err(WorkerError {
            kind: ErrorKind::BadJob,
            message: "this job is one shard of an evaluation; its part is not a result".into(),
        }),
        Evaluated::Robustness(doc) => Ok(doc.control),
        Evaluated::SuitePart(_) => Err(WorkerError {
            kind: ErrorKind::BadJob,
            message: "this job is one shard of a robustness evaluation; its part is not a result"
                .into(),
        }),
        Evaluated::Race(_) => Err(WorkerError {
            kind: ErrorKind::BadJob,
            message: "this job is a race of two policies; its report is not a result".into(),
        }),
    }
}

/// [`run_job`] for any job, by its [`JobKind`]: a shard job runs only that
/// shard ([`EvalRun::shard`]) and gives its part, a suite job level 0 and
/// every level, a race job the race. `on_progress` gets the
/// initial states' outcomes as they complete, in the evaluation's random
/// order ([`Progress::states`]).
pub fn run_job_or_shard(
    job: &Job,
    on_progress: &mut dyn FnMut(&Progress),
) -> Result<Evaluated, WorkerError> {
    let to_worker = |e: EvalError| WorkerError {
        kind: e.kind(),
        message: e.to_string(),
    };
    let task = LoadedTask::load_obs(job.task, job.manifest.obs_type).map_err(|e| WorkerError {
        kind: match e {
            TaskError::Unavailable(_) | TaskError::NoImageVariant(_) => ErrorKind::BadJob,
            _ => ErrorKind::Internal,
        },
        message: e.to_string(),
    })?;
    let suite = match job.kind.suite() {
        Some(name) => {
            let suite = crate::robustness::suite_for(name, job.task, job.manifest.obs_type)
                .map_err(to_worker)?;
            // A dry run only checks that the suite exists.
            job.dry_run_steps.is_none().then_some(suite)
        }
        None => None,
    };
    let (mut policy, info) = load_policy(job, &task).map_err(to_worker)?;
    // "Loaded, 0 done": the supervisor then attributes a limit hit in the first
    // query to running the rollouts, not to loading the policy.
    if let Ok(set) = task.def.context_set() {
        let (n_ctx, per_ctx) = protocol_size(&task, job.protocol, set.len());
        let n = match job.kind.shard().map(|s| s.contexts(n_ctx)) {
            Some(Ok(range)) => range.len(),
            _ => n_ctx,
        };
        on_progress(&Progress::counts(0, n * per_ctx));
    }
    let opts = EvalOptions {
        protocol: job.protocol,
        seed: job.seed,
        step_cap: job.dry_run_steps,
        build: job.build.clone(),
        ..EvalOptions::default()
    };
    if let JobKind::Race(race) = &job.kind {
        return run_race(job, race, &task, policy.as_mut(), &info, &opts, on_progress)
            .map(|r| Evaluated::Race(Box::new(r)))
            .map_err(to_worker);
    }
    if let Some(suite) = suite {
        let plan =
            crate::robustness::plan(&task, policy.as_ref(), &opts, &suite).map_err(to_worker)?;
        let mut counts = |d: usize, t: usize| on_progress(&Progress::counts(d, t));
        // With a shard, the same block of whole initial states at level 0
        // and at every level (`d3il eval --suite robustness --shard K/N`).
        let recorded = match job.kind.shard() {
            Some(shard) => {
                let states = shard
                    .contexts(plan.n_contexts)
                    .map_err(|e| to_worker(EvalError::Setup(e.to_string())))?
                    .len();
                states * plan.rollouts_per_context * (plan.levels.len() + 1)
            }
            None => plan.recorded,
        };
        let mut observer = crate::robustness::Cumulative::new(&mut counts, recorded);
        return crate::suite_shard::evaluate_suite_or_shard(
            &task,
            policy.as_mut(),
            &info,
            &opts,
            &suite,
            &plan,
            job.kind.shard(),
            &mut observer,
        )
        .map(|run| match run {
            SuiteRun::Part(part) => Evaluated::SuitePart(part),
            SuiteRun::Whole(doc) => Evaluated::Robustness(doc),
        })
        .map_err(to_worker);
    }
    // A plain job, a shard, or a suite's dry run (the plain evaluation or shard).
    match job.kind.shard() {
        Some(shard) => {
            let run = EvalRun::shard(shard).reporting(on_progress);
            evaluate(&task, policy.as_mut(), &info, &opts, run)
                .map(|(p, _)| Evaluated::Part(Box::new(p)))
        }
        None => evaluate(
            &task,
            policy.as_mut(),
            &info,
            &opts,
            EvalRun::all().reporting(on_progress),
        )
        .map(|(r, _)| Evaluated::Result(Box::new(r))),
    }
    .map_err(to_worker)
}

/// A race job ([`JobKind::Race`]): the job's policy is A, the race's B, loaded
/// the same way ([`load_policy`]) on the same task variant; one progress
/// report per pair, carrying where the test stands.
fn run_race(
    job: &Job,
    race: &RaceJob,
    task: &LoadedTask,
    policy_a: &mut dyn Policy,
    info_a: &PolicyInfo,
    opts: &EvalOptions,
    on_progress: &mut dyn FnMut(&Progress),
) -> Result<RaceReport, EvalError> {
    if race.manifest_b.obs_type != job.manifest.obs_type {
        return Err(EvalError::Setup(format!(
            "A takes {} observations and B {}: a race runs both on the same task variant",
            job.manifest.obs_type, race.manifest_b.obs_type
        )));
    }
    let job_b = Job {
        policy: race.policy_b.clone(),
        manifest: race.manifest_b.clone(),
        kind: JobKind::Plain,
        ..job.clone()
    };
    let (mut policy_b, info_b) = load_policy(&job_b, task)?;
    let race_opts = RaceOptions {
        alpha: race.alpha,
        delta: race.delta,
    };
    let opts = EvalOptions {
        max_live: race.max_live.max(1),
        ..opts.clone()
    };
    let per_state = |p: &RaceProgress| p.a.successes.len() + p.b.successes.len();
    let mut total = 0;
    race::race(
        task,
        Contender {
            policy: policy_a,
            info: info_a,
        },
        Contender {
            policy: policy_b.as_mut(),
            info: &info_b,
        },
        &opts,
        &race_opts,
        &mut |p| {
            total = total.max(p.states_total * per_state(p));
            on_progress(&Progress {
                rollouts_done: p.states * per_state(p),
                rollouts_total: total,
                states: Vec::new(),
                race: Some(Box::new(p.clone())),
            })
        },
    )
}
