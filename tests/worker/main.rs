//! The real `d3il worker` process on ONNX files and remote endpoints: results,
//! sandboxing, TLS, concurrency and nothing left behind (worker_common sets the
//! process's TMPDIR and working directory once, so only these tests share this
//! binary). One module per former test file.

mod worker_common;

mod worker_concurrent;
mod worker_onnx;
mod worker_remote;
mod worker_sandbox;
mod worker_tls;
