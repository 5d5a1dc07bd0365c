//! The typed values of the store's text columns. Every enum below is a
//! `sqlx::Type` stored as lowercase text, and the protocol's own enums (task,
//! observation type, protocol) decode through [`Slug`]: a row holding anything
//! else fails to decode with an error naming the column, instead of being
//! read as an empty or default value.

use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use std::fmt;
use std::str::FromStr;

macro_rules! text_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $v:ident = $s:literal),+ $(,)? }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, sqlx::Type, serde::Serialize, utoipa::ToSchema)]
        #[sqlx(rename_all = "lowercase")]
        #[serde(rename_all = "lowercase")]
        pub enum $name { $($(#[$vm])* $v),+ }

        impl $name {
            pub fn as_str(self) -> &'static str {
                match self { $($name::$v => $s),+ }
            }
        }

        impl fmt::Display for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                f.write_str(self.as_str())
            }
        }

        impl PartialEq<&str> for $name {
            fn eq(&self, other: &&str) -> bool {
                self.as_str() == *other
            }
        }
    };
}

text_enum!(
    /// Where a job is in the durable queue.
    JobState {
        Queued = "queued",
        /// A worker slot holds its lease.
        Leased = "leased",
        Done = "done",
        Failed = "failed",
    }
);

text_enum!(
    /// A submission's status as submitters see it.
    SubmissionStatus {
        Queued = "queued",
        Running = "running",
        Completed = "completed",
        Failed = "failed",
    }
);

text_enum!(
    /// How a submission's policy is run.
    PolicyKind {
        /// An uploaded ONNX file.
        Onnx = "onnx",
        /// A remote endpoint.
        Remote = "remote",
    }
);

/// A stored slug (`aligning`, `state`, `paper`): the column type through which
/// the protocol's enums are read (`#[sqlx(try_from = "Slug")]`).
#[derive(Debug, Clone, sqlx::Type)]
#[sqlx(transparent)]
pub struct Slug(pub String);

/// A stored slug that names nothing (the error sqlx reports for the column).
#[derive(Debug, thiserror::Error)]
#[error("stored data is corrupt: {0}")]
pub struct BadSlug(String);

impl TryFrom<Slug> for TaskId {
    type Error = BadSlug;
    fn try_from(s: Slug) -> Result<Self, BadSlug> {
        TaskId::from_str(&s.0).map_err(|e| BadSlug(e.to_string()))
    }
}

impl TryFrom<Slug> for ObsType {
    type Error = BadSlug;
    fn try_from(s: Slug) -> Result<Self, BadSlug> {
        ObsType::from_str(&s.0).map_err(BadSlug)
    }
}

impl TryFrom<Slug> for ProtocolKind {
    type Error = BadSlug;
    fn try_from(s: Slug) -> Result<Self, BadSlug> {
        ProtocolKind::from_str(&s.0).map_err(BadSlug)
    }
}
