"""Shared fixtures of the Python suite (CTest test python_pytest; docs/PYTHON.md "Tests")."""

import os
import pathlib
import subprocess

import pytest

SOURCE = pathlib.Path(os.environ.get("DVISIM_SOURCE_DIR", pathlib.Path(__file__).resolve().parents[2]))


def cli_path():
    p = os.environ.get("DVISIM_CLI")
    if p:
        return p
    for cand in (SOURCE / "build" / "bin" / "dvisim",):
        if cand.exists():
            return str(cand)
    return None


@pytest.fixture(scope="session")
def cli():
    p = cli_path()
    if not p:
        pytest.skip("the dvisim CLI is not built (DVISIM_CLI or build/bin/dvisim)")
    return p


@pytest.fixture(scope="session")
def source():
    return SOURCE


def run_cli(cli, *args, check=True):
    r = subprocess.run([cli, *map(str, args)], capture_output=True, text=True)
    if check and r.returncode != 0:
        raise AssertionError(f"dvisim {' '.join(map(str, args))} failed ({r.returncode}): {r.stderr}")
    return r
