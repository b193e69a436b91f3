#!/usr/bin/env bash
# Light volumes of every frame of an animated scene, as a Slurm job array
# (docs/CLUSTER.md). Submit from the folder the paths are relative to, e.g.
# the repository's root:
#
#   sbatch docs/cluster/slurm-array.sh
#   SCENE=shots/fly.toml OUT=/shared/fly-light/ sbatch --array=0-15 docs/cluster/slurm-array.sh
#
# Each array task runs `eikon simulate` over its share of the frames: eikon
# reads SLURM_ARRAY_TASK_ID and SLURM_ARRAY_TASK_COUNT itself, so task K of
# N takes every N-th frame from the K-th. Any number of tasks works: change
# --array on the sbatch command line (it overrides the lines below). OUT
# must be on a file system every node sees. Submit again to finish what a
# failed, cancelled or killed run left: frames already done are skipped.
#
# Settings, from the environment (sbatch passes the submitter's on):
#   SCENE        the scene (default configs/orbit.toml, 48 frames)
#   FRAMES       A..B, A, or all (default all)
#   OUT          the output folder (default orbit-light/)
#   EIKON        the eikon binary (default: eikon on PATH)
#   EIKON_FLAGS  more flags for simulate, split at spaces
#                (e.g. "--resolution 64", "--backend cpu", "--force")
#
#SBATCH --job-name=eikon-light
#SBATCH --array=0-3
#SBATCH --ntasks=1
#SBATCH --output=eikon-light-%A_%a.out
# One task uses all the cores it can see; on a cluster that shares nodes,
# give it some (remove one '#' to enable):
##SBATCH --cpus-per-task=8
set -euo pipefail

SCENE="${SCENE:-configs/orbit.toml}"
FRAMES="${FRAMES:-all}"
OUT="${OUT:-orbit-light/}"
EIKON="${EIKON:-eikon}"
read -r -a flags <<<"${EIKON_FLAGS:-}"

if ! command -v "$EIKON" >/dev/null; then
    echo "slurm-array.sh: no eikon binary at '$EIKON': put eikon on PATH or set EIKON" >&2
    exit 2
fi
if [ -z "${SLURM_ARRAY_TASK_ID:-}" ]; then
    echo "slurm-array.sh: not a Slurm array task: one process runs every frame" >&2
fi

# No --shard: eikon takes the shard from SLURM_ARRAY_TASK_ID and
# SLURM_ARRAY_TASK_COUNT, and says so on stderr.
status=0
"$EIKON" simulate "$SCENE" --frames "$FRAMES" -o "$OUT" "${flags[@]}" || status=$?

# Once every task has ended, `eikon status "$OUT"` lists the frames done,
# missing and failed, and exits 0 only when all are done. To have Slurm run
# it after the array: sbatch --dependency=afterany:<array job id> --wrap 'eikon status OUT/'
echo "slurm-array.sh: task ${SLURM_ARRAY_TASK_ID:-(none)} exited $status; when all tasks are done: $EIKON status $OUT" >&2
exit "$status"
