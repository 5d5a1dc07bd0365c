//! Fuzz harnesses of every parser of outside input (docs/reliability.md,
//! "Fuzzing"). Each target is a plain `fn(&[u8])` that feeds the bytes to
//! the same function production calls and checks properties of the answer:
//! it panics (which the fuzzer reports as a crash) when a parser panics,
//! when an error carries no message, or when a property fails (a manifest
//! that parses re-serialises to the same value, parts merge the same in any
//! order, the HTTP routes answer bad input 4xx with a message, never 5xx).
//!
//! The afl.rs binaries in `fuzz/` call these functions; the test
//! `tests/corpus.rs` runs every committed corpus file and every crash
//! regression input through them, so the harnesses keep compiling and the
//! crashes stay fixed.

mod api;
mod files;
mod onnx;
mod remote;
mod replay;

pub use api::{api_query, form, upload};
pub use files::{contexts, manifest, merge};
pub use onnx::{confine_like_worker, onnx_admit};
pub use remote::{remote_frame, valid_replies};
pub use replay::replay;

/// A fuzz target: its name (the directory of its corpus, `fuzz/corpus/<name>`)
/// and its harness.
pub struct Target {
    pub name: &'static str,
    pub run: fn(&[u8]),
}

/// Every target, in the order `scripts/fuzz` runs them.
pub const TARGETS: &[Target] = &[
    Target {
        name: "manifest",
        run: manifest,
    },
    Target {
        name: "contexts",
        run: contexts,
    },
    Target {
        name: "replay",
        run: replay,
    },
    Target {
        name: "merge",
        run: merge,
    },
    Target {
        name: "upload",
        run: upload,
    },
    Target {
        name: "api_query",
        run: api_query,
    },
    Target {
        name: "remote_frame",
        run: remote_frame,
    },
    Target {
        name: "onnx_admit",
        run: onnx_admit,
    },
];

/// The target called `name`.
pub fn target(name: &str) -> Option<&'static Target> {
    TARGETS.iter().find(|t| t.name == name)
}

/// An error a user sees must say something: a message of at least a few
/// characters (the project's rule is "what was wrong and what to do").
fn assert_described(what: &str, e: &dyn std::fmt::Display) {
    let text = e.to_string();
    assert!(
        text.trim().len() >= 8,
        "{what}: an error without a usable message: {text:?}"
    );
}

#[cfg(test)]
mod tests {
    #[test]
    fn an_error_without_a_message_is_a_finding() {
        assert!(std::panic::catch_unwind(|| super::assert_described("x", &"")).is_err());
        assert!(std::panic::catch_unwind(|| super::assert_described("x", &"  e  ")).is_err());
        super::assert_described("x", &"the manifest has no `task`");
    }
}
