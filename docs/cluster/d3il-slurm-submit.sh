#!/bin/bash
# Submits a sharded D3IL evaluation to Slurm (docs/cluster.md): an array of
# N shards (d3il-array.sbatch) and a merge job that runs once all of them
# succeeded (d3il-merge.sbatch). Prints "ARRAY_JOB_ID MERGE_JOB_ID".
#
#   docs/cluster/d3il-slurm-submit.sh TASK POLICY SHARDS OUT.json
#
# Further settings (D3IL_PROTOCOL, D3IL_SEED, D3IL_PARTS, D3IL_EVAL_ARGS, D3IL)
# are read from the environment and passed on to both jobs; extra sbatch
# options (partition, account, time limit) go in SBATCH_* variables as usual.
set -euo pipefail
if [ $# -ne 4 ]; then
  echo "usage: $0 TASK POLICY SHARDS OUT.json   (e.g. aligning \$PWD/policy.onnx 6 aligning.json)" >&2
  exit 2
fi
here=$(cd "$(dirname "$0")" && pwd)
export D3IL_TASK=$1 D3IL_POLICY=$2 D3IL_SHARDS=$3 D3IL_OUT=$4
array=$(sbatch --parsable --array="1-$D3IL_SHARDS" --export=ALL "$here/d3il-array.sbatch")
array=${array%%;*}
merge=$(sbatch --parsable --dependency="afterok:$array" --kill-on-invalid-dep=yes \
  --export=ALL "$here/d3il-merge.sbatch")
echo "${array} ${merge%%;*}"
