#!/usr/bin/env bash
# Make this checkout ready to run pardem: Debian packages (MPICH, parallel HDF5), then a virtual
# environment with mpi4py and h5py built against them, then pardem itself (editable).
# Idempotent: a second run checks and returns in about a second.
#   bash setup.sh            # installs what is missing
#   PARDEM_VENV=/path bash setup.sh   # another place for the virtual environment (default .venv)
set -euo pipefail
here="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
venv="${PARDEM_VENV:-$here/.venv}"
py="${PYTHON:-python3}"
say() { echo "[setup] $*" >&2; }

# 1. System packages. Explicit MPICH names: Open MPI may own the plain mpicc/mpirun alternatives.
need_apt=()
command -v mpicc.mpich >/dev/null 2>&1 || need_apt+=(mpich)
command -v mpiexec.mpich >/dev/null 2>&1 || need_apt+=(mpich)
dpkg -s libhdf5-mpich-dev >/dev/null 2>&1 || need_apt+=(libhdf5-mpich-dev)
command -v pkg-config >/dev/null 2>&1 || need_apt+=(pkg-config)
command -v cc >/dev/null 2>&1 || need_apt+=(gcc)
"$py" -c "import venv, ensurepip" >/dev/null 2>&1 || need_apt+=(python3-venv)
"$py" -c "import sysconfig, os, sys; sys.exit(not os.path.exists(os.path.join(sysconfig.get_paths()['include'], 'Python.h')))" \
  || need_apt+=(python3-dev)
if [ ${#need_apt[@]} -gt 0 ]; then
  say "installing Debian packages: ${need_apt[*]}"
  sudo_cmd=""; [ "$(id -u)" -ne 0 ] && sudo_cmd="sudo"
  $sudo_cmd apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $sudo_cmd apt-get install -y -qq --no-install-recommends "${need_apt[@]}" >/dev/null
fi

# 2. Virtual environment.
[ -x "$venv/bin/python" ] || { say "creating virtual environment $venv"; "$py" -m venv "$venv"; }
vpy="$venv/bin/python"
stamp="$venv/.pardem-setup-stamp"
want="$(cat "$here/pyproject.toml" "$here/setup.sh" | sha256sum | cut -d' ' -f1)"
check='import mpi4py.MPI, h5py, numba, meshio, pytest, pardem; assert h5py.get_config().mpi, "h5py lacks MPI"'
if [ -f "$stamp" ] && [ "$(cat "$stamp")" = "$want" ] && "$vpy" -c "$check" >/dev/null 2>&1; then
  exit 0
fi

# 3. Python packages. mpi4py and h5py from source against MPICH (the PyPI wheels look for other
# MPI libraries); -O1 keeps mpi4py's build under 1 GB of memory and 2 minutes.
say "installing Python packages into $venv (first time: about 5 minutes)"
"$vpy" -m pip install -q -U pip setuptools wheel Cython pkgconfig numpy
if ! "$vpy" -c "import mpi4py.MPI" >/dev/null 2>&1; then
  say "building mpi4py against MPICH"
  MPI4PY_BUILD_MPICC=mpicc.mpich CFLAGS="-O1 -g0" \
    "$vpy" -m pip install -q --no-binary=mpi4py "mpi4py>=4.0"
fi
if ! "$vpy" -c "import h5py, sys; sys.exit(not h5py.get_config().mpi)" >/dev/null 2>&1; then
  say "building h5py against parallel HDF5 (MPICH)"
  "$vpy" -m pip uninstall -q -y h5py >/dev/null 2>&1 || true
  CC=mpicc.mpich HDF5_MPI=ON HDF5_PKGCONFIG_NAME=hdf5-mpich \
    "$vpy" -m pip install -q --no-binary=h5py --no-build-isolation "h5py>=3.10"
fi
"$vpy" -m pip install -q --no-build-isolation -e "$here[test]"
"$vpy" -c "$check"
echo "$want" > "$stamp"
say "ready: $venv"
