"""The examples of examples/python/ in their quick mode: they run, and write what they say they write."""

import os
import subprocess
import sys

import pytest

EXAMPLES = ["pile_height_profile.py", "ces_voltage_sweep.py", "gpu_pile_cupy.py"]


@pytest.mark.parametrize("name", EXAMPLES)
def test_example_runs_quick(source, tmp_path, name):
    env = dict(os.environ, MPLBACKEND="Agg")
    r = subprocess.run([sys.executable, str(source / "examples" / "python" / name), "--quick", "--out", str(tmp_path)]
                       if name != "gpu_pile_cupy.py" else
                       [sys.executable, str(source / "examples" / "python" / name), "--quick"],
                       capture_output=True, text=True, env=env, timeout=120)
    assert r.returncode == 0, r.stderr
    if name == "pile_height_profile.py":
        assert (tmp_path / "pile_height_profile.png").stat().st_size > 1000 and "mean height" in r.stdout
    elif name == "ces_voltage_sweep.py":
        assert (tmp_path / "ces_voltage_sweep.png").stat().st_size > 1000
        assert len((tmp_path / "ces_voltage_sweep.csv").read_text().splitlines()) == 3
    else:
        assert "skipped" in r.stdout or "mean height" in r.stdout
