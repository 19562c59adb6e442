"""`cmake --install` puts an importable package under the prefix (the interpreter's site folder there)."""

import os
import pathlib
import subprocess
import sys

import pytest


def test_cmake_install_gives_an_importable_package(tmp_path):
    build = os.environ.get("DVISIM_BUILD_DIR")
    if not build:
        pytest.skip("DVISIM_BUILD_DIR not set (CTest sets it)")
    subprocess.run(["cmake", "--install", build, "--prefix", str(tmp_path), "--component", "python"], check=True,
                   capture_output=True)
    found = sorted(tmp_path.rglob("dvisim/__init__.py"))
    assert len(found) == 1 and any(tmp_path.rglob("dvisim/_dvisim*.so"))
    site = found[0].parent.parent
    env = dict(os.environ, PYTHONPATH=str(site))
    r = subprocess.run([sys.executable, "-c", "import dvisim, numpy as np; s = dvisim.System(backend='cpu'); "
                        "s.add_spheres(np.zeros((1, 3)), 0.1, density=1); s.step(10); print(dvisim.__file__)"],
                       capture_output=True, text=True, env=env, cwd=str(tmp_path))
    assert r.returncode == 0, r.stderr
    assert pathlib.Path(r.stdout.strip()).resolve().is_relative_to(tmp_path.resolve())


def test_default_install_folder_is_on_this_interpreters_path(tmp_path):
    build = os.environ.get("DVISIM_BUILD_DIR")
    if not build:
        pytest.skip("DVISIM_BUILD_DIR not set (CTest sets it)")
    cache = pathlib.Path(build, "CMakeCache.txt").read_text()
    rel = next(l.split("=", 1)[1] for l in cache.splitlines() if l.startswith("DVISIM_PYTHON_INSTALL_DIR:"))
    prefix = next(l.split("=", 1)[1] for l in cache.splitlines() if l.startswith("CMAKE_INSTALL_PREFIX:"))
    if not any(p.endswith("dist-packages") for p in sys.path):
        pytest.skip("not a Debian-style Python")
    assert os.path.join(prefix, rel) in sys.path  # `cmake --install build` as root: importable at once
