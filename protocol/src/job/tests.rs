//! The job's wire format and manifest checks.

use super::*;

fn manifest() -> PolicyManifest {
    serde_json::from_str(r#"{"task": "aligning", "history": 5, "horizon": 4, "execute": 4}"#)
        .unwrap()
}

#[test]
fn an_endpoint_secret_travels_in_the_job_but_never_prints() {
    let secret = EndpointSecret::new("s3cret-s3cret-s3cret").unwrap();
    let policy = PolicySource::Remote {
        url: "ws://host:1/".into(),
        secret: Some(secret.clone()),
    };
    let json = serde_json::to_string(&policy).unwrap();
    assert_eq!(
        json,
        r#"{"kind":"remote","url":"ws://host:1/","secret":"s3cret-s3cret-s3cret"}"#
    );
    assert_eq!(serde_json::from_str::<PolicySource>(&json).unwrap(), policy);
    assert!(!format!("{policy:?}").contains("s3cret"), "{policy:?}");
    // Jobs without a secret read and write as before.
    let plain: PolicySource =
        serde_json::from_str(r#"{"kind":"remote","url":"ws://host:1/"}"#).unwrap();
    assert_eq!(
        serde_json::to_string(&plain).unwrap(),
        r#"{"kind":"remote","url":"ws://host:1/"}"#
    );
    let e = EndpointSecret::new("short").unwrap_err();
    assert!(e.contains("5 characters; give 16 to 256"), "{e}");
    let e = EndpointSecret::new("with a space in the middle").unwrap_err();
    assert!(e.contains("' '") && e.contains("no spaces"), "{e}");
}

#[test]
fn manifest_limits_are_stated_once() {
    let m = manifest();
    assert_eq!(m.window, WindowMode::Pad);
    m.validate().unwrap();
    let bad = |f: &dyn Fn(&mut PolicyManifest)| {
        let mut m = manifest();
        f(&mut m);
        m.validate().unwrap_err()
    };
    let e = bad(&|m| m.history = 0);
    assert_eq!(e.field, "history");
    assert!(e.to_string().contains("from 1 to 64"), "{e}");
    assert_eq!(bad(&|m| m.history = 65).field, "history");
    assert_eq!(bad(&|m| m.horizon = 1025).field, "horizon");
    let e = bad(&|m| m.execute = 5);
    assert_eq!(e.field, "execute");
    assert!(e.to_string().contains("horizon H = 4"), "{e}");
    let e = bad(&|m| {
        m.normalisation = Some(Normalisation {
            obs_std: Some(vec![1.0, 0.0]),
            ..Default::default()
        })
    });
    assert_eq!(e.field, "normalisation.obs_std");
    let mut at_max = manifest();
    at_max.history = PolicyManifest::MAX_HISTORY;
    at_max.horizon = PolicyManifest::MAX_HORIZON;
    at_max.execute = PolicyManifest::MAX_HORIZON;
    at_max.validate().unwrap();
}

#[test]
fn manifest_window_mode_parses_and_is_checked_against_the_task() {
    let m: PolicyManifest =
        serde_json::from_str(r#"{"task": "aligning", "history": 5, "window": "grow"}"#).unwrap();
    assert_eq!(m.window, WindowMode::Grow);
    let e = serde_json::from_str::<PolicyManifest>(r#"{"task": "aligning", "window": "grew"}"#)
        .unwrap_err();
    assert!(
        e.to_string().contains("pad") && e.to_string().contains("grow"),
        "{e}"
    );
    let spec = crate::TaskSpec {
        task: TaskId::Aligning,
        obs_dim: 20,
        act_dim: 3,
        max_steps: 400,
        n_behaviours: 2,
    };
    m.validate_for(&spec).unwrap();
    let mut n = m.clone();
    n.normalisation = Some(Normalisation {
        act_mean: Some(vec![0.0; 2]),
        ..Default::default()
    });
    let e = n.validate_for(&spec).unwrap_err();
    assert_eq!(e.field, "normalisation.act_mean");
    assert!(
        e.to_string()
            .contains("has 2 entries but task aligning needs 3"),
        "{e}"
    );
    let other = crate::TaskSpec {
        task: TaskId::Avoiding,
        ..spec
    };
    assert_eq!(m.validate_for(&other).unwrap_err().field, "task");
}

/// A job of each kind as JSON, with `kind_fields` beside the job's own.
fn job_json(kind_fields: &str) -> String {
    let job = Job {
        job_id: "7".into(),
        task: TaskId::Aligning,
        protocol: ProtocolKind::Quick,
        policy: PolicySource::Scripted {
            name: "aligning:inside".into(),
        },
        manifest: manifest(),
        seed: 3,
        limits: Limits::default(),
        assets_dir: "assets".into(),
        dry_run_steps: None,
        build: None,
        kind: JobKind::Plain,
    };
    let mut v = serde_json::to_value(&job).unwrap();
    v.as_object_mut().unwrap().remove("kind");
    let fields: serde_json::Value = serde_json::from_str(kind_fields).unwrap();
    for (k, x) in fields.as_object().unwrap() {
        v[k] = x.clone();
    }
    v.to_string()
}

fn race() -> crate::race::RaceJob {
    crate::race::RaceJob {
        policy_b: PolicySource::Scripted {
            name: "aligning:outside".into(),
        },
        manifest_b: manifest(),
        alpha: 0.05,
        delta: None,
        max_live: 4,
    }
}

#[test]
fn each_job_kind_writes_its_tag_and_its_fields_and_reads_back() {
    let shard = crate::shard::Shard { index: 2, count: 3 };
    let suite = SuiteName::Robustness;
    for (kind, fields) in [
        (JobKind::Plain, r#"{"kind":"plain"}"#.to_string()),
        (
            JobKind::Shard(shard),
            r#"{"kind":"shard","shard":{"index":2,"count":3}}"#.to_string(),
        ),
        (
            JobKind::Suite(suite),
            r#"{"kind":"suite","suite":"robustness"}"#.to_string(),
        ),
        (
            JobKind::SuiteShard { suite, shard },
            r#"{"kind":"suite_shard","shard":{"index":2,"count":3},"suite":"robustness"}"#
                .to_string(),
        ),
        (
            JobKind::Race(Box::new(race())),
            format!(
                r#"{{"kind":"race","race":{}}}"#,
                serde_json::to_string(&race()).unwrap()
            ),
        ),
    ] {
        let json = job_json(&fields);
        let job: Job = serde_json::from_str(&json).unwrap();
        assert_eq!(job.kind, kind, "{json}");
        // The kind's fields sit beside the job's own, in this order.
        let written = serde_json::to_string(&job).unwrap();
        let tail = &fields[1..fields.len() - 1];
        assert!(written.contains(tail), "{written} lacks {tail}");
        assert_eq!(serde_json::from_str::<Job>(&written).unwrap(), job);
        assert_eq!(kind.tag(), fields[9..].split('"').next().unwrap());
    }
}

/// Jobs written before `kind` existed (by a server or `d3il eval` of
/// 0.6.0 and earlier) read as the kind their optional fields make.
#[test]
fn a_job_written_before_kinds_existed_reads_as_its_fields_say() {
    let shard = crate::shard::Shard { index: 1, count: 2 };
    let race_json = serde_json::to_string(&race()).unwrap();
    for (fields, kind) in [
        ("{}".to_string(), JobKind::Plain),
        (
            r#"{"shard":{"index":1,"count":2}}"#.to_string(),
            JobKind::Shard(shard),
        ),
        (
            r#"{"suite":"robustness"}"#.to_string(),
            JobKind::Suite(SuiteName::Robustness),
        ),
        (
            r#"{"suite":"robustness","shard":{"index":1,"count":2}}"#.to_string(),
            JobKind::SuiteShard {
                suite: SuiteName::Robustness,
                shard,
            },
        ),
        (
            format!(r#"{{"race":{race_json}}}"#),
            JobKind::Race(Box::new(race())),
        ),
    ] {
        let job: Job = serde_json::from_str(&job_json(&fields)).unwrap();
        assert_eq!(job.kind, kind, "{fields}");
    }
}

#[test]
fn a_job_whose_fields_contradict_its_kind_is_refused_with_the_reason() {
    let race_json = serde_json::to_string(&race()).unwrap();
    let refused = |fields: &str| {
        serde_json::from_str::<Job>(&job_json(fields))
            .unwrap_err()
            .to_string()
    };
    let e = refused(&format!(r#"{{"race":{race_json},"suite":"robustness"}}"#));
    assert!(e.contains("a race runs two whole plain evaluations"), "{e}");
    let e = refused(r#"{"kind":"plain","shard":{"index":1,"count":2}}"#);
    assert!(
        e.contains("a job of kind `plain` has `shard`: that kind takes no `shard`"),
        "{e}"
    );
    let e = refused(r#"{"kind":"suite_shard","suite":"robustness"}"#);
    assert!(
        e.contains("a job of kind `suite_shard` lacks `shard`: that kind needs `shard`"),
        "{e}"
    );
    let e = refused(r#"{"kind":"robustness"}"#);
    assert!(e.contains("unknown variant `robustness`"), "{e}");
    let e = refused(r#"{"suite":"fragility"}"#);
    assert!(
        e.contains("unknown variant `fragility`, expected `robustness`"),
        "{e}"
    );
}

#[test]
fn suite_names_parse_and_print_as_one_constant() {
    assert_eq!(SuiteName::parse("robustness"), Ok(SuiteName::Robustness));
    assert_eq!(SuiteName::Robustness.to_string(), "robustness");
    assert_eq!(
        serde_json::to_string(&SuiteName::Robustness).unwrap(),
        r#""robustness""#
    );
    assert_eq!(
        "fragility".parse::<SuiteName>().unwrap_err(),
        "suite `fragility`: the one suite is `robustness`"
    );
}

#[test]
fn limits_without_an_extra_ca_keep_their_json() {
    // A job's limits as written before the field existed still parse.
    let old = r#"{"memory_bytes":1,"cpu_seconds":2,"wall_seconds":3,"open_files":4,
        "file_size_bytes":5,"remote_deadline_ms":6,"remote_frame_bytes":7,
        "allow_private_endpoints":true}"#;
    let l: Limits = serde_json::from_str(old).unwrap();
    assert_eq!(l.extra_ca_pem, None);
    assert_eq!(l.remote_frame_bytes, 7);
    // And without a CA nothing new is written.
    let json = serde_json::to_string(&Limits::default()).unwrap();
    assert!(!json.contains("extra_ca_pem"), "{json}");
    let with = Limits {
        extra_ca_pem: Some("-----BEGIN CERTIFICATE-----\n".into()),
        ..Limits::default()
    };
    let back: Limits = serde_json::from_str(&serde_json::to_string(&with).unwrap()).unwrap();
    assert_eq!(back, with);
}
