"""The GPU backend from Python (skipped without a device): the state as device arrays through
__cuda_array_interface__, checked against the host copy and against the CPU backend stepping the same pile.

On a machine with a GPU: PYTHONPATH=build/python python3 -m pytest -q python/tests/test_gpu.py (CuPy, where
installed, reads the arrays in place; without it the interface itself is checked)."""

import ctypes

import numpy as np
import pytest

import dvisim

HAVE_GPU, GPU_NAME = dvisim.gpu_available()
pytestmark = pytest.mark.skipif(not HAVE_GPU, reason=f"no usable GPU device ({GPU_NAME})")


def pile(backend, n=512):
    s = dvisim.System(backend=backend, solver="apgd", iterations=50)
    s.add_body(dvisim.Plane(), fixed=True)
    side = int(round(n ** (1 / 3))) + 1
    g = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)[:n]
    s.add_spheres(g * 0.0211 + [0, 0.0105, 0], 0.01, density=2500)
    return s


def copy_device(ptr, nbytes):
    cudart = ctypes.CDLL("libcudart.so")
    host = np.empty(nbytes, dtype=np.uint8)
    assert cudart.cudaMemcpy(host.ctypes.data_as(ctypes.c_void_p), ctypes.c_void_p(ptr), ctypes.c_size_t(nbytes),
                             2) == 0  # cudaMemcpyDeviceToHost
    return host


def test_device_arrays_hold_the_state():
    s = pile("gpu")
    s.step(20)
    dev = s.device_arrays()
    host = np.array(s.positions)  # a copy of the host mirror
    cai = dev["positions"].__cuda_array_interface__
    assert cai["shape"] == (s.body_count, 3) and cai["version"] == 3 and cai["data"][0] != 0
    try:
        import cupy
    except ImportError:
        cupy = None
    if cupy is not None:
        got = cupy.asnumpy(cupy.asarray(dev["positions"]))
    else:
        itemsize = 8 if cai["typestr"] == "<f8" else 4
        got = copy_device(cai["data"][0], s.body_count * 3 * itemsize).view(cai["typestr"]).reshape(-1, 3)
    assert np.array_equal(got, host)  # the device array is the state, bit for bit
    assert dev["rotations"].__cuda_array_interface__["shape"] == (s.body_count, 4)


def test_gpu_backend_agrees_with_cpu():
    # the GPU runs the CPU's per-element functions with the same rounding (no FMA contraction): the pile settles alike
    a, b = pile("gpu"), pile("cpu")
    a.step(30)
    b.step(30)
    assert np.allclose(a.positions, b.positions, rtol=0, atol=1e-4)
