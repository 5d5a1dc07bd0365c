//! OpenAPI schemas of the protocol's types as the API writes them (the
//! `protocol` crate knows nothing of OpenAPI). Fields of those types in the
//! view structs name these with `#[schema(value_type = ...)]`; the document
//! itself is generated from the view structs in `http::api::openapi`.

use d3il_protocol::{ObsType, ProtocolKind, TaskId};
use std::borrow::Cow;
use utoipa::openapi::schema::{ObjectBuilder, Schema, Type};
use utoipa::openapi::RefOr;
use utoipa::{PartialSchema, ToSchema};

fn text_enum(description: &str, values: Vec<serde_json::Value>) -> RefOr<Schema> {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .description(Some(description))
        .enum_values(Some(values))
        .into()
}

macro_rules! slug_schema {
    ($(#[$m:meta])* $name:ident = $title:literal, $desc:literal, $values:expr) => {
        $(#[$m])*
        pub struct $name;

        impl PartialSchema for $name {
            fn schema() -> RefOr<Schema> {
                text_enum($desc, $values)
            }
        }

        impl ToSchema for $name {
            fn name() -> Cow<'static, str> {
                Cow::Borrowed($title)
            }
        }
    };
}

slug_schema!(
    /// A task's slug.
    Task = "Task",
    "A D3IL task",
    TaskId::ALL.iter().map(|t| t.slug().into()).collect()
);

slug_schema!(
    /// `state` or `image`.
    Obs = "ObsType",
    "What the policy observes",
    vec![ObsType::State.as_str().into(), ObsType::Image.as_str().into()]
);

slug_schema!(
    /// `meshes` or `primitives`.
    RobotLook = "RobotLook",
    "How an image evaluation drew the robot: the Panda's meshes (as the original) or primitive shapes",
    d3il_protocol::RobotLook::ALL
        .iter()
        .map(|l| l.as_str().into())
        .collect()
);

slug_schema!(
    /// `paper` or `quick`.
    Protocol = "Protocol",
    "The evaluation protocol: the paper's, or a quick smoke run",
    // As serde writes them.
    [ProtocolKind::Paper, ProtocolKind::Quick]
        .iter()
        .filter_map(|p| serde_json::to_value(p).ok())
        .collect()
);

slug_schema!(
    /// `reported` (the paper's numbers) or `evaluated` (run here).
    Source = "Source",
    "Where a leaderboard row's numbers come from",
    [d3il_protocol::Source::Reported, d3il_protocol::Source::Evaluated]
        .iter()
        .filter_map(|p| serde_json::to_value(p).ok())
        .collect()
);

/// Mean and sample standard deviation over training seeds.
#[derive(utoipa::ToSchema)]
#[allow(dead_code)] // a schema only: the values are `d3il_protocol::Stat`
pub struct Stat {
    pub mean: f64,
    pub std: f64,
}

slug_schema!(
    /// How a rollout ended (`d3il_protocol::Ending`).
    Ending = "Ending",
    "How a rollout ended: task_success (the task ended it, succeeded), task_ended (ended by the task without success), time_limit (ran to the step limit), sim_unstable (the simulation became unstable), step_cap (dry runs only)",
    d3il_protocol::Ending::ALL
        .iter()
        .map(|e| e.name().into())
        .collect()
);

/// Bytes of a file (a video), as OpenAPI writes binary content.
pub struct Binary;

impl PartialSchema for Binary {
    fn schema() -> RefOr<Schema> {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .format(Some(utoipa::openapi::SchemaFormat::KnownFormat(
                utoipa::openapi::KnownFormat::Binary,
            )))
            .into()
    }
}

impl ToSchema for Binary {
    fn name() -> Cow<'static, str> {
        Cow::Borrowed("Binary")
    }
}
