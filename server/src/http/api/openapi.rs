//! The OpenAPI 3.1 document of the API, generated (utoipa) from the handlers'
//! `#[utoipa::path]` annotations and the `ToSchema` view structs, so the
//! document describes exactly what the handlers return.

use crate::error::{ErrorBody, ErrorDetail};
use crate::schema;
use crate::views::{
    LeaderboardList, LeaderboardView, MethodList, ResultsView, SubmissionView, WhoAmI,
};
use utoipa::openapi::schema::{ObjectBuilder, Schema, Type};
use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
use utoipa::openapi::RefOr;
use utoipa::{Modify, OpenApi};

#[derive(OpenApi)]
#[openapi(
    info(
        title = "D3IL leaderboard API",
        version = "1",
        description = "Submit imitation-learning policies for evaluation on the D3IL tasks and read leaderboards. Errors always have the shape {\"error\": {\"code\", \"message\", \"field\"}}. See docs/api.md."
    ),
    servers((url = "/api/v1")),
    paths(
        super::create_submission,
        super::list_submissions,
        super::get_submission,
        super::cancel::cancel_submission,
        super::get_results,
        super::robustness::get_robustness,
        super::zoo::get_provenance,
        super::list_leaderboards,
        super::get_leaderboard,
        super::get_leaderboard_csv,
        super::list_methods,
        super::whoami,
        super::get_build,
        super::admin::withdraw,
        super::admin::reinstate,
        super::admin::baseline,
        super::admin::revoke,
        super::admin::set_quota,
        super::admin::audit,
        super::compare::compare,
        super::races::create_race,
        super::races::get_race,
        super::races::cancel_race,
        super::rollouts::list_rollouts,
        super::rollouts::get_rollout,
        super::rollouts::get_video,
        super::rollouts::get_paths_svg,
    ),
    components(schemas(
        ErrorBody,
        ErrorDetail,
        SubmissionView,
        ResultsView,
        super::robustness::RobustnessDocument,
        crate::zoo::ProvenanceView,
        NewSubmissionForm,
        LeaderboardList,
        LeaderboardView,
        MethodList,
        crate::views::SubmissionList,
        WhoAmI,
        crate::views::CreatedView,
        super::races::CreatedRaceView,
        crate::quota::QuotaView,
        crate::quota::QuotaCount,
        crate::store::Withdrawal,
        crate::store::AuditEntry,
        super::admin::AdminDone,
        super::admin::AuditList,
        super::admin::WithdrawRequest,
        super::admin::BaselineRequest,
        super::admin::QuotaRequest,
        crate::views::BuildView,
        crate::canary::CanaryState,
        schema::Task,
        schema::Obs,
        schema::Protocol,
        schema::Ending,
        crate::rollouts::RolloutList,
        crate::rollouts::RolloutItem,
        crate::rollouts::RolloutDetail,
        crate::races::RaceRequest,
        crate::races::RaceView,
        crate::store::RaceStatus,
        crate::races::RaceLive,
    )),
    modifiers(&BearerToken, &RaceAliases),
    tags(
        (name = "submissions", description = "Submitting policies and following their evaluation"),
        (name = "leaderboards", description = "Reported and evaluated results"),
        (name = "rollouts", description = "What a policy did: rollouts by outcome and behaviour, records with their traces, videos and pictures"),
        (name = "races", description = "Races of two submissions: both policies on the same initial states, stopped as soon as the sequential paired test decides (docs/sequential.md). The same routes under /comparisons are deprecated aliases. (The paired comparison of two finished results is GET /compare.)"),
        (name = "admin", description = "Moderation and quotas, for admin tokens; every action is written to the audit log"),
    )
)]
struct ApiDoc;

/// The versions of the Python client (`d3il-client`, clients/python) this API
/// accepts, as a PEP 440 specifier: the client's major version is the API's
/// (`info.version`). Published as `info.x-d3il-client-versions`, so an older
/// or newer client says what to install instead of failing on a changed field.
pub const CLIENT_VERSIONS: &str = ">=1.0,<2";

/// The document served at `/api/v1/openapi.json`.
pub fn document() -> utoipa::openapi::OpenApi {
    let mut doc = ApiDoc::openapi();
    doc.info
        .extensions
        .get_or_insert_with(Default::default)
        .insert("x-d3il-client-versions".into(), CLIENT_VERSIONS.into());
    doc
}

struct BearerToken;

impl Modify for BearerToken {
    fn modify(&self, doc: &mut utoipa::openapi::OpenApi) {
        doc.components
            .get_or_insert_with(Default::default)
            .add_security_scheme(
                "bearer",
                SecurityScheme::Http(
                    HttpBuilder::new()
                        .scheme(HttpAuthScheme::Bearer)
                        .description(Some("Token from `d3il token create --name <you>`"))
                        .build(),
                ),
            );
    }
}

/// The deprecated `/comparisons…` aliases of the `/races…` routes
/// (`super::race_aliases`): the same operations, marked deprecated, each
/// naming its successor.
struct RaceAliases;

impl Modify for RaceAliases {
    fn modify(&self, doc: &mut utoipa::openapi::OpenApi) {
        use super::races::{OLD_PREFIX, PREFIX};
        use utoipa::openapi::Deprecated;
        let aliases: Vec<(String, utoipa::openapi::PathItem)> = doc
            .paths
            .paths
            .iter()
            .filter_map(|(path, item)| {
                let rest = path.strip_prefix(PREFIX)?;
                let mut item = item.clone();
                for op in [&mut item.get, &mut item.post].into_iter().flatten() {
                    op.deprecated = Some(Deprecated::True);
                    op.operation_id = op.operation_id.as_ref().map(|id| format!("{id}_deprecated_alias"));
                    op.description = Some(format!(
                        "Deprecated alias of `{PREFIX}{rest}`, answered exactly as it is, with the headers \
                         `Deprecation: true` and `Link: </api/v1{PREFIX}{rest}>; rel=\"successor-version\"`."
                    ));
                }
                Some((format!("{OLD_PREFIX}{rest}"), item))
            })
            .collect();
        doc.paths.paths.extend(aliases);
    }
}

/// `?view=`: `main` or `data-fraction`.
pub fn view_schema() -> RefOr<Schema> {
    ObjectBuilder::new()
        .schema_type(Type::String)
        .enum_values(Some(
            [
                crate::leaderboard::View::Main,
                crate::leaderboard::View::DataFraction,
            ]
            .map(|v| v.as_str()),
        ))
        .default(Some("main".into()))
        .into()
}

/// The multipart/form-data fields of a new submission (the same fields the
/// HTML form posts, without its `token`).
#[derive(utoipa::ToSchema)]
#[allow(dead_code)] // a schema only: intake reads the fields from the form
pub struct NewSubmissionForm {
    /// Method name (1-64 characters).
    method: String,
    history: Option<i64>,
    backbone: Option<String>,
    prediction: Option<String>,
    diversity: Option<String>,
    code_url: Option<String>,
    paper_url: Option<String>,
    description: Option<String>,
    #[schema(value_type = schema::Task)]
    task: String,
    /// Default `state`.
    #[schema(value_type = Option<schema::Obs>)]
    obs_type: Option<String>,
    training_seed: i64,
    /// Default 1.0.
    data_fraction: Option<f64>,
    /// Default `paper`.
    #[schema(value_type = Option<schema::Protocol>)]
    protocol: Option<String>,
    /// The ONNX policy file.
    #[schema(value_type = Option<String>, format = Binary)]
    onnx: Option<Vec<u8>>,
    /// Policy manifest JSON (required with `onnx`).
    manifest: Option<String>,
    /// ws(s)/http(s) URL of a remote policy (instead of `onnx`).
    endpoint_url: Option<String>,
    /// With `endpoint_url`: a shared secret (16-256 visible ASCII characters)
    /// the evaluator sends in the WebSocket handshake as `Authorization:
    /// Bearer <secret>`, so that the endpoint can refuse everyone else
    /// (docs/remote-protocol.md, "Shared secret"). Stored, and never shown
    /// again by any page or answer, not even to its submitter.
    #[schema(write_only)]
    endpoint_secret: Option<String>,
    /// `robustness`: evaluate the task's perturbation suite too (level 0 is
    /// the plain result; `/submissions/{id}/robustness` has the rest).
    /// Refused for tasks and observation types without a suite.
    suite: Option<String>,
}
