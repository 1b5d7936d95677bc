#!/usr/bin/env bash
# Idempotent set-up: Debian packages (Open MPI, parallel HDF5, FFTW), a .venv
# with h5py built against parallel HDF5, and hpcves installed in editable mode.
# Every step checks first and does nothing when its result is already there,
# so a second run takes a few seconds.
set -euo pipefail

cd "$(dirname "$0")/.."
VENV=${VENV:-.venv}
PY=${PYTHON:-python3}
WHEELS=${HPCVES_WHEEL_CACHE:-$HOME/.cache/hpcves/wheels}
HDF5_DIR=${HDF5_DIR:-/usr/lib/x86_64-linux-gnu/hdf5/openmpi}
APT_PACKAGES="openmpi-bin libopenmpi-dev libhdf5-openmpi-dev libfftw3-dev pkg-config"

say() { printf '[bootstrap] %s\n' "$*"; }

# 1. Debian packages -------------------------------------------------------
missing=()
for p in $APT_PACKAGES; do
    dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -gt 0 ]; then
    say "installing Debian packages: ${missing[*]}"
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then
        command -v sudo >/dev/null || { echo "bootstrap: need root or sudo to install ${missing[*]}" >&2; exit 1; }
        SUDO=sudo
    fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# 2. virtual environment ---------------------------------------------------
if [ ! -x "$VENV/bin/python" ]; then
    say "creating $VENV"
    "$PY" -m venv "$VENV"
fi
VPY="$VENV/bin/python"
pipq() { "$VPY" -m pip install -q --disable-pip-version-check "$@"; }

# 3. h5py with MPI (parallel HDF5) ------------------------------------------
if ! "$VPY" -c "import h5py, sys; sys.exit(0 if h5py.get_config().mpi else 1)" 2>/dev/null; then
    pipq "setuptools>=77" packaging wheel cython pkgconfig numpy mpi4py
    mkdir -p "$WHEELS"
    whl=$(ls "$WHEELS"/h5py-*.whl 2>/dev/null | head -n1 || true)
    if [ -z "$whl" ]; then
        say "building h5py against parallel HDF5 (takes about 3 minutes, once; cached in $WHEELS)"
        CC=mpicc HDF5_MPI=ON HDF5_DIR="$HDF5_DIR" \
            "$VPY" -m pip wheel -q --no-deps --no-binary=h5py --no-build-isolation \
            --no-cache-dir -w "$WHEELS" h5py
        whl=$(ls "$WHEELS"/h5py-*.whl | head -n1)
    fi
    pipq --force-reinstall --no-deps "$whl"
    if ! "$VPY" -c "import h5py, sys; sys.exit(0 if h5py.get_config().mpi else 1)"; then
        echo "bootstrap: $whl is not an MPI build of h5py; delete it and rerun" >&2
        exit 1
    fi
fi

# 4. hpcves and the rest of its dependencies --------------------------------
stamp="$VENV/.hpcves-installed"
# (again where the editable install points at another clone: scripts run from bench/ or analysis/
# would import that clone's hpcves)
here="$(pwd -P)"
case "$VPY" in /*) vpy_abs="$VPY" ;; *) vpy_abs="$here/$VPY" ;; esac
if [ ! -f "$stamp" ] || [ pyproject.toml -nt "$stamp" ] || ! (cd / && "$vpy_abs" -c \
        "import hpcves, os, sys; sys.exit(0 if os.path.realpath(hpcves.__file__).startswith('$here/') else 1)") \
        2>/dev/null; then
    say "installing hpcves (editable) and its dependencies"
    pipq -e ".[test]"
    touch "$stamp"
fi
