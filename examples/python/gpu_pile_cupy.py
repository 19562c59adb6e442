"""A pile on the GPU backend whose state CuPy reads in place, without a copy through the host (docs/PYTHON.md).

    PYTHONPATH=build/python python3 examples/python/gpu_pile_cupy.py [--n 100000] [--steps 200]

Skipped (exit 0, with a message) where there is no GPU device or no CuPy. System.device_arrays() gives the
positions, rotations and velocities as objects with __cuda_array_interface__: cupy.asarray, torch.as_tensor(...,
device="cuda") and numba.cuda.as_cuda_array take them as they are.
"""

import argparse
import sys

import numpy as np

import dvisim


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, default=100000)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--quick", action="store_true")
    a = ap.parse_args()
    if a.quick:
        a.n, a.steps = 2000, 20
    ok, name = dvisim.gpu_available()
    if not ok:
        print(f"skipped: no GPU device ({name})")
        return 0
    try:
        import cupy
    except ImportError:
        print("skipped: CuPy is not installed")
        return 0
    sim = dvisim.System(backend="gpu")
    sim.add_body(dvisim.Plane(), fixed=True)
    side = int(np.ceil(np.sqrt(a.n / 20)))
    k = np.arange(a.n)
    pos = np.column_stack([k % side, k // (side * side), (k // side) % side]) * 0.021 + 0.0105
    sim.add_spheres(pos, 0.01, density=2500)
    sim.step(a.steps)
    p = cupy.asarray(sim.device_arrays()["positions"])  # device memory, no host round trip
    print(f"{a.n} spheres on {sim.device}: mean height {float(p[1:, 1].mean()):.4f} m after {a.steps} steps")
    return 0


if __name__ == "__main__":
    sys.exit(main())
