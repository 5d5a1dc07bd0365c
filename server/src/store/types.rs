//! The typed values of the store's text columns. Every enum below is a
//! `sqlx::Type` stored as lowercase text, and the protocol's own enums (task,
//! observation type, protocol) decode through [`Stored`]: a row holding anything
//! else fails to decode with an error naming the column, instead of being
//! read as an empty or default value.

use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use sqlx::error::BoxDynError;
use sqlx::sqlite::{Sqlite, SqliteTypeInfo, SqliteValueRef};
use sqlx::{Decode, Type};
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

/// A stored slug (`aligning`, `state`, `paper`) read as the protocol's enum
/// `T` (`#[sqlx(try_from = "Stored<TaskId>")]`): text that names nothing
/// fails to decode, with an error naming the column and the value.
#[derive(Debug, Clone, Copy)]
pub struct Stored<T>(pub T);

impl<T> Type<Sqlite> for Stored<T> {
    fn type_info() -> SqliteTypeInfo {
        <String as Type<Sqlite>>::type_info()
    }

    fn compatible(ty: &SqliteTypeInfo) -> bool {
        <String as Type<Sqlite>>::compatible(ty)
    }
}

impl<'r, T> Decode<'r, Sqlite> for Stored<T>
where
    T: FromStr,
    T::Err: fmt::Display,
{
    fn decode(value: SqliteValueRef<'r>) -> Result<Self, BoxDynError> {
        let text = <&str as Decode<Sqlite>>::decode(value)?;
        T::from_str(text)
            .map(Stored)
            .map_err(|e| format!("stored data is corrupt: {e}").into())
    }
}

macro_rules! from_stored {
    ($($t:ty),+) => {$(
        impl From<Stored<$t>> for $t {
            fn from(s: Stored<$t>) -> $t {
                s.0
            }
        }
    )+};
}

from_stored!(TaskId, ObsType, ProtocolKind);
