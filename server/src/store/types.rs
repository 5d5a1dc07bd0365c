//! The typed values of the store's text columns. Every enum below is a
//! `sqlx::Type` stored as lowercase text, and the protocol's own enums (task,
//! observation type, protocol) decode through [`Stored`]: a row holding anything
//! else fails to decode with an error naming the column, instead of being
//! read as an empty or default value. JSON columns are TEXT on both backends
//! and decode through [`Json`].
//!
//! Every impl here is generic over the database (SQLite and PostgreSQL):
//! a value is stored as the backend's text type.

use d3il_protocol::{EndpointSecret, ObsType, ProtocolKind, TaskId};
use sqlx::encode::IsNull;
use sqlx::error::BoxDynError;
use sqlx::{Database, Decode, Encode, Type};
use std::fmt;
use std::str::FromStr;

/// Implements `Type` (the backend's text type) for `$t`.
macro_rules! text_type {
    ([$($g:tt)*] $t:ty) => {
        impl<DB: Database, $($g)*> Type<DB> for $t
        where
            str: Type<DB>,
            for<'a> &'a str: Type<DB>,
        {
            fn type_info() -> DB::TypeInfo {
                <str as Type<DB>>::type_info()
            }

            fn compatible(ty: &DB::TypeInfo) -> bool {
                <&str as Type<DB>>::compatible(ty)
            }
        }
    };
}

macro_rules! text_enum {
    ($(#[$m:meta])* $name:ident { $($(#[$vm:meta])* $v:ident = $s:literal),+ $(,)? }) => {
        $(#[$m])*
        #[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, serde::Serialize, utoipa::ToSchema)]
        #[serde(rename_all = "lowercase")]
        pub enum $name { $($(#[$vm])* $v),+ }

        impl $name {
            pub fn as_str(self) -> &'static str {
                match self { $($name::$v => $s),+ }
            }
        }

        impl FromStr for $name {
            type Err = String;
            fn from_str(s: &str) -> Result<Self, String> {
                match s {
                    $($s => Ok($name::$v),)+
                    other => Err(format!("`{other}` is not a {}", stringify!($name))),
                }
            }
        }

        text_type!([] $name);

        impl<'q, DB: Database> Encode<'q, DB> for $name
        where
            &'q str: Encode<'q, DB>,
        {
            fn encode_by_ref(&self, buf: &mut DB::ArgumentBuffer) -> Result<IsNull, BoxDynError> {
                <&str as Encode<DB>>::encode(self.as_str(), buf)
            }
        }

        impl<'r, DB: Database> Decode<'r, DB> for $name
        where
            &'r str: Decode<'r, DB>,
        {
            fn decode(value: DB::ValueRef<'r>) -> Result<Self, BoxDynError> {
                let text = <&str as Decode<DB>>::decode(value)?;
                text.parse().map_err(|e: String| format!("stored data is corrupt: {e}").into())
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
    /// Where a race (`POST /api/v1/races`) stands.
    RaceStatus {
        /// Waiting for the race slot.
        Queued = "queued",
        /// A race slot holds its lease and runs it.
        Running = "running",
        Completed = "completed",
        Failed = "failed",
        /// Cancelled by its starter or an admin.
        Cancelled = "cancelled",
    }
);

impl RaceStatus {
    /// Queued or running: it can still be cancelled.
    pub fn is_active(self) -> bool {
        matches!(self, RaceStatus::Queued | RaceStatus::Running)
    }
}

text_enum!(
    /// How a submission's policy is run.
    PolicyKind {
        /// An uploaded ONNX file.
        Onnx = "onnx",
        /// A remote endpoint.
        Remote = "remote",
    }
);

/// A remote endpoint's shared secret as stored (`submissions.endpoint_secret`):
/// text that decodes into the protocol's [`EndpointSecret`], whose `Debug`
/// hides it, so a logged row cannot leak it.
#[derive(Debug, Clone)]
pub struct StoredSecret(pub EndpointSecret);

text_type!([] StoredSecret);

impl<'r, DB: Database> Decode<'r, DB> for StoredSecret
where
    &'r str: Decode<'r, DB>,
{
    fn decode(value: DB::ValueRef<'r>) -> Result<Self, BoxDynError> {
        let text = <&str as Decode<DB>>::decode(value)?;
        EndpointSecret::new(text)
            .map(StoredSecret)
            .map_err(|e| format!("stored data is corrupt: {e}").into())
    }
}

/// A stored slug (`aligning`, `state`, `paper`) read as the protocol's enum
/// `T` (`task: Stored<TaskId>` in a `from_row!`): text that names nothing
/// fails to decode, with an error naming the column and the value.
#[derive(Debug, Clone, Copy)]
pub struct Stored<T>(pub T);

text_type!([T] Stored<T>);

impl<'r, DB: Database, T> Decode<'r, DB> for Stored<T>
where
    T: FromStr,
    T::Err: fmt::Display,
    &'r str: Decode<'r, DB>,
{
    fn decode(value: DB::ValueRef<'r>) -> Result<Self, BoxDynError> {
        let text = <&str as Decode<DB>>::decode(value)?;
        T::from_str(text)
            .map(Stored)
            .map_err(|e| format!("stored data is corrupt: {e}").into())
    }
}

/// A JSON document in a TEXT column (both backends), decoded into `T`: a
/// column that does not hold a `T` fails to decode.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
#[serde(transparent)]
pub struct Json<T>(pub T);

text_type!([T] Json<T>);

impl<T> std::ops::Deref for Json<T> {
    type Target = T;
    fn deref(&self) -> &T {
        &self.0
    }
}

impl<'r, DB: Database, T> Decode<'r, DB> for Json<T>
where
    T: serde::de::DeserializeOwned,
    &'r str: Decode<'r, DB>,
{
    fn decode(value: DB::ValueRef<'r>) -> Result<Self, BoxDynError> {
        let text = <&str as Decode<DB>>::decode(value)?;
        Ok(Json(serde_json::from_str(text)?))
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
