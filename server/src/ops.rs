//! What the `d3il` command-line tools use of the server's store, in one
//! place: the binary crate names these, never `store` itself (a layout test
//! of the workspace refuses `d3il_server::store` under `src/`). Everything
//! here is a re-export, so each type and rule still has one definition, in
//! the store.

/// Opening a database: the target (`sqlite:` path or PostgreSQL URL) and the
/// store handle the commands query (`d3il tables`, `d3il db`, the benches).
pub use crate::store::{DbTarget, Store};

/// Tokens and quotas (`d3il token`): a token's shown prefix and one
/// submitter's quota overrides.
pub use crate::store::{QuotaOverrides, TOKEN_PREFIX_LEN};

/// Seeding a store with methods and submissions (benchmarks and tests of the
/// commands) and reading a submission's status back.
pub use crate::store::{NewMethod, NewPolicy, NewSubmission, SubmissionStatus};

/// The marker in the name of a policy file still being written; a file that
/// carries it after a crash is a leftover (the chaos bench's audit).
pub use crate::store::TMP_MARKER;

/// The SQL driver the store is built on, for benches that read a PostgreSQL
/// database directly.
pub use crate::store::sqlx;
