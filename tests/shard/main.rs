//! Sharded evaluations: `d3il eval --shard` and merge, Slurm arrays, the
//! Kubernetes manifests and robustness shards in a store. One test binary; one
//! module per former test file.

mod shard_support;

mod k8s_manifests;
mod robustness_store_shards;
mod shard_cli;
mod slurm_array;
