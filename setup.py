"""`pip install .`: builds the dvisim Python module with the project's CMake build and installs the package
(docs/PYTHON.md "Installing").

There is deliberately no pyproject.toml: pip then builds with the setuptools and wheel it finds installed (Debian 12:
python3-setuptools, python3-wheel) instead of downloading them into an isolated build environment, so the
install works offline. The C++ build needs what .ci/deps.sh installs (cmake, a compiler, Bullet, pybind11-dev,
python3-dev). Environment:
  DVISIM_PIP_BUILD_DIR   the CMake build folder (default: build-pip in the checkout; kept, so a second install
                         rebuilds only what changed)
  DVISIM_CMAKE_ARGS      more CMake arguments, e.g. "-DDVISIM_ENABLE_CUDA=OFF" or
                         "-DCMAKE_CXX_COMPILER_LAUNCHER=ccache"
  DVISIM_PIP_JOBS        parallel compile jobs (default: the number of cores)
"""

import os
import pathlib
import shlex
import shutil
import subprocess
import sys

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

ROOT = pathlib.Path(__file__).resolve().parent


class CMakeBuild(build_ext):
    """Builds the target _dvisim (python/CMakeLists.txt) and copies the module into the wheel."""

    def build_extension(self, ext):
        build_dir = pathlib.Path(os.environ.get("DVISIM_PIP_BUILD_DIR", ROOT / "build-pip"))
        jobs = os.environ.get("DVISIM_PIP_JOBS", str(os.cpu_count() or 1))
        configure = ["cmake", "-S", str(ROOT), "-B", str(build_dir), "-DCMAKE_BUILD_TYPE=Release",
                     f"-DDVISIM_PYTHON_EXECUTABLE={sys.executable}", "-DDVISIM_BUILD_PYTHON=ON",
                     "-DDVISIM_BUILD_TESTS=OFF", "-DDVISIM_BUILD_DEMOS=OFF", "-DDVISIM_BUILD_BENCH=OFF"]
        configure += shlex.split(os.environ.get("DVISIM_CMAKE_ARGS", ""))
        subprocess.check_call(configure)
        subprocess.check_call(["cmake", "--build", str(build_dir), "--target", "_dvisim", "-j", jobs])
        built = sorted((build_dir / "python" / "dvisim").glob("_dvisim*.so"))
        if not built:
            raise RuntimeError(f"the CMake build made no module in {build_dir}/python/dvisim")
        dest = pathlib.Path(self.get_ext_fullpath(ext.name))
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(built[0], dest)


setup(
    name="dvisim",
    version="0.1.0",
    description="DVI multibody engine for dense granular flows (CPU/OpenMP, GPU), with a CES separator model",
    packages=["dvisim"],
    package_dir={"": "python"},
    ext_modules=[Extension("dvisim._dvisim", sources=[])],
    cmdclass={"build_ext": CMakeBuild},
    python_requires=">=3.9",
    install_requires=["numpy"],
    zip_safe=False,
    # setuptools' own folders beside CMake's (not in build/, the README's CMake build)
    options={"build": {"build_base": str(pathlib.Path(os.environ.get("DVISIM_PIP_BUILD_DIR", ROOT / "build-pip"))
                                          / "setuptools")},
             "egg_info": {"egg_base": str(pathlib.Path(os.environ.get("DVISIM_PIP_BUILD_DIR", ROOT / "build-pip")))}},
)
