#!/bin/bash
# Slurm batch job for the compress driver on a cluster. Submit from the repository root:
#     sbatch drivers/slurm_compress.sh
# One MPI rank per core; pardem's ranks are single-threaded (Numba kernels without threads),
# so request one CPU per task and pin the thread pools to one thread.
#SBATCH --job-name=pardem-compress
#SBATCH --nodes=2
#SBATCH --ntasks-per-node=32
#SBATCH --cpus-per-task=1
#SBATCH --time=02:00:00
#SBATCH --output=pardem-%j.out

set -euo pipefail
module load mpich hdf5-mpich 2>/dev/null || true   # site-specific: MPI and parallel HDF5 modules
export OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
# Numba's on-disk cache must be writable and shared by the ranks of a node
export NUMBA_CACHE_DIR="${SLURM_SUBMIT_DIR}/.numba-cache"
VENV="${PARDEM_VENV:-$SLURM_SUBMIT_DIR/.venv}"

# Compile the kernels once before the parallel start (otherwise every rank compiles them).
"$VENV/bin/python" -m pardem.drivers.compress --steps 1 --quiet --out "runs/warmup-$SLURM_JOB_ID" >/dev/null

srun "$VENV/bin/python" -m pardem.drivers.compress \
    --config drivers/compress_default.toml \
    --set domain.box=[0.05,0.05,0.05] \
    --out "runs/compress-$SLURM_JOB_ID"
