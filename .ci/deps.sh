#!/usr/bin/env bash
# Installs dvisim's build dependencies from Debian 12's packages, only those missing.
# Needs root (or sudo). Safe to run again: it does nothing when everything is present.
set -euo pipefail
# clang, libclang-rt-14-dev (libFuzzer and the sanitizer runtimes) and libomp-dev (OpenMP for clang): the fuzz
# tests (CTest label fuzz, docs/HARDENING.md) build an instrumented tree with them. clang-format (14 in Debian 12):
# the format check (CTest test clang_format, tests/check_format.sh). libopenmpi-dev and openmpi-bin (mpirun): the
# domain decomposition over MPI (DVISIM_ENABLE_MPI, on where CMake finds MPI) and its tests (CTest label mpi).
# pybind11-dev, python3-dev and python3-numpy: the Python module (DVISIM_BUILD_PYTHON, docs/PYTHON.md);
# python3-pytest its tests (CTest test python_pytest); python3-setuptools, python3-wheel, python3-pip and
# python3-venv an offline `pip install .`.
pkgs=(build-essential cmake pkg-config libbullet-dev libbullet-extras-dev libeigen3-dev catch2
      nlohmann-json3-dev libcli11-dev python3 python3-matplotlib clang libclang-rt-14-dev libomp-dev clang-format
      libopenmpi-dev openmpi-bin pybind11-dev python3-dev python3-numpy python3-pytest python3-setuptools
      python3-wheel python3-pip python3-venv)
missing=()
for p in "${pkgs[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
[ ${#missing[@]} -eq 0 ] && exit 0
echo "dvisim: installing ${missing[*]}"
SUDO=""
[ "$(id -u)" -eq 0 ] || SUDO="sudo"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
