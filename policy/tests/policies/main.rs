//! The policy crate's integration tests, one test binary: ONNX fixtures and
//! agents under tract, remote endpoints over websockets and TLS (the Python
//! policy servers of clients/python). One module per former test file.

mod common;

mod agent_fixtures;
mod onnx_fixtures;
mod remote;
mod tls;
