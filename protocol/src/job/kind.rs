//! What a job evaluates ([`JobKind`]) and which suite ([`SuiteName`]), with
//! the job's wire form of them.

use serde::{Deserialize, Serialize};

/// The perturbation suite a job, a submission (`suite=robustness`) or
/// `d3il eval --suite` asks for (docs/robustness.md): which suite file that
/// is depends on the task and observation type (the evaluator's
/// `robustness::suite_for`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum SuiteName {
    /// The robustness track: level 0 and every level of the task's suite.
    Robustness,
}

impl SuiteName {
    /// Every suite name there is.
    pub const ALL: [SuiteName; 1] = [SuiteName::Robustness];

    pub fn as_str(self) -> &'static str {
        match self {
            SuiteName::Robustness => "robustness",
        }
    }

    /// The suite named `name`, or a message naming the ones there are.
    pub fn parse(name: &str) -> Result<SuiteName, String> {
        SuiteName::ALL
            .into_iter()
            .find(|s| s.as_str() == name)
            .ok_or_else(|| {
                let names: Vec<String> = SuiteName::ALL
                    .iter()
                    .map(|s| format!("`{}`", s.as_str()))
                    .collect();
                format!("suite `{name}`: the one suite is {}", names.join(", "))
            })
    }
}

impl std::fmt::Display for SuiteName {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

impl std::str::FromStr for SuiteName {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        SuiteName::parse(s)
    }
}

/// What a job evaluates, and so what the worker answers with
/// ([`Evaluated`]). One variant per mode: a race of a suite, or a suite
/// shard without its suite, cannot be written.
///
/// On the wire (inside the job's object) the tag `kind` and the variant's
/// fields, named as before 0.6.1: `{"kind": "plain"}`, `{"kind": "shard",
/// "shard": {"index": 2, "count": 3}}`, `{"kind": "suite", "suite":
/// "robustness"}`, `{"kind": "suite_shard", "suite": ..., "shard": ...}`,
/// `{"kind": "race", "race": {...}}`. A job written before `kind` existed
/// (optional `shard`, `suite` and `race` fields) reads as the kind its
/// fields make; fields that contradict the tag, or a race with a suite or a
/// shard, are refused with a message saying so.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "KindFields", into = "KindFields")]
pub enum JobKind {
    /// The whole protocol: an [`EvalResult`].
    Plain,
    /// One shard (whole initial states): its [`crate::shard::EvalPart`],
    /// which a server joins with the other shards' (any worker host runs
    /// one).
    Shard(crate::shard::Shard),
    /// The perturbation suite: level 0 (the plain evaluation) and every
    /// level, a [`crate::robustness::RobustnessResult`]. A dry run with a
    /// suite only checks that the suite exists, then runs as a plain one.
    Suite(SuiteName),
    /// The shard's part of level 0 and of every level of the suite
    /// ([`crate::robustness::RobustnessPart`]); a dry run runs the plain shard.
    SuiteShard {
        suite: SuiteName,
        shard: crate::shard::Shard,
    },
    /// A sequential race: the job's policy is A, the race's B; a
    /// [`crate::race::RaceReport`].
    Race(Box<crate::race::RaceJob>),
}

impl JobKind {
    /// The kind of a suite or plain evaluation of all initial states or of
    /// `shard`.
    pub fn of(suite: Option<SuiteName>, shard: Option<crate::shard::Shard>) -> JobKind {
        match (suite, shard) {
            (None, None) => JobKind::Plain,
            (None, Some(shard)) => JobKind::Shard(shard),
            (Some(suite), None) => JobKind::Suite(suite),
            (Some(suite), Some(shard)) => JobKind::SuiteShard { suite, shard },
        }
    }

    /// The shard the job runs, if it runs one.
    pub fn shard(&self) -> Option<crate::shard::Shard> {
        match self {
            JobKind::Shard(shard) | JobKind::SuiteShard { shard, .. } => Some(*shard),
            _ => None,
        }
    }

    /// The suite the job runs, if it runs one.
    pub fn suite(&self) -> Option<SuiteName> {
        match self {
            JobKind::Suite(suite) | JobKind::SuiteShard { suite, .. } => Some(*suite),
            _ => None,
        }
    }

    /// The race, if the job is one.
    pub fn race(&self) -> Option<&crate::race::RaceJob> {
        match self {
            JobKind::Race(race) => Some(race),
            _ => None,
        }
    }

    /// The wire tag (`kind`) of this kind.
    pub fn tag(&self) -> &'static str {
        self.wire_tag().as_str()
    }

    fn wire_tag(&self) -> KindTag {
        match self {
            JobKind::Plain => KindTag::Plain,
            JobKind::Shard(_) => KindTag::Shard,
            JobKind::Suite(_) => KindTag::Suite,
            JobKind::SuiteShard { .. } => KindTag::SuiteShard,
            JobKind::Race(_) => KindTag::Race,
        }
    }
}

/// The wire tag of a [`JobKind`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
enum KindTag {
    Plain,
    Shard,
    Suite,
    SuiteShard,
    Race,
}

impl KindTag {
    fn as_str(self) -> &'static str {
        match self {
            KindTag::Plain => "plain",
            KindTag::Shard => "shard",
            KindTag::Suite => "suite",
            KindTag::SuiteShard => "suite_shard",
            KindTag::Race => "race",
        }
    }
}

/// A [`JobKind`] as its fields sit in a job's JSON object.
#[derive(Serialize, Deserialize)]
struct KindFields {
    /// Absent in jobs written before 0.6.1.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    kind: Option<KindTag>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    shard: Option<crate::shard::Shard>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    suite: Option<SuiteName>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    race: Option<Box<crate::race::RaceJob>>,
}

impl From<JobKind> for KindFields {
    fn from(kind: JobKind) -> Self {
        let mut fields = KindFields {
            kind: Some(kind.wire_tag()),
            shard: kind.shard(),
            suite: kind.suite(),
            race: None,
        };
        if let JobKind::Race(race) = kind {
            fields.race = Some(race);
        }
        fields
    }
}

impl TryFrom<KindFields> for JobKind {
    type Error = String;

    fn try_from(f: KindFields) -> Result<Self, String> {
        let tag = match f.kind {
            Some(tag) => tag,
            // Written before 0.6.1: the fields say which kind it is.
            None => match (&f.race, f.suite, f.shard) {
                (Some(_), None, None) => KindTag::Race,
                (Some(_), _, _) => {
                    return Err(
                        "the job has `race` together with `suite` or `shard`: a race runs two \
                         whole plain evaluations; queue the race, or the suite or shard, alone"
                            .into(),
                    )
                }
                (None, suite, shard) => JobKind::of(suite, shard).wire_tag(),
            },
        };
        let present = [
            ("shard", f.shard.is_some()),
            ("suite", f.suite.is_some()),
            ("race", f.race.is_some()),
        ];
        let wanted: &[&str] = match tag {
            KindTag::Plain => &[],
            KindTag::Shard => &["shard"],
            KindTag::Suite => &["suite"],
            KindTag::SuiteShard => &["suite", "shard"],
            KindTag::Race => &["race"],
        };
        for (field, is) in present {
            if is != wanted.contains(&field) {
                let (has, needs) = if is {
                    ("has", "takes no")
                } else {
                    ("lacks", "needs")
                };
                return Err(format!(
                    "a job of kind `{}` {has} `{field}`: that kind {needs} `{field}` \
                     (kinds: plain, shard, suite, suite_shard, race)",
                    tag.as_str()
                ));
            }
        }
        Ok(match (tag, f.suite, f.shard, f.race) {
            (KindTag::Plain, ..) => JobKind::Plain,
            (KindTag::Shard, _, Some(shard), _) => JobKind::Shard(shard),
            (KindTag::Suite, Some(suite), ..) => JobKind::Suite(suite),
            (KindTag::SuiteShard, Some(suite), Some(shard), _) => {
                JobKind::SuiteShard { suite, shard }
            }
            (KindTag::Race, _, _, Some(race)) => JobKind::Race(race),
            _ => unreachable!("the fields were checked against the kind"),
        })
    }
}
