"""dvisim: the DVI multibody engine for dense granular flows, from Python (docs/PYTHON.md).

    import dvisim, numpy as np
    sim = dvisim.System(backend="cpu", dt=1e-3)
    sim.add_body(dvisim.Plane((0, 1, 0), 0.0), fixed=True)
    ids = sim.add_spheres(np.random.rand(1000, 3), 0.01, density=2500)
    sim.step(100)
    print(sim.positions[ids].mean(axis=0))     # a view of the engine's array, no copy (cpu backend)

Bad input raises dvisim.InputError (a ValueError) with the one-line message `dvisim run` prints; a diverged
simulation, a solver failure and a device error raise RuntimeError subclasses.
"""

import json
import math
import os

import numpy as np

from . import _dvisim
from ._dvisim import DeviceError, InputError, SimulationDiverged, SolverError
from .shapes import Box, Capsule, Cone, Cylinder, Ellipsoid, Hull, Plane, Shape, Sphere

__all__ = ["System", "load_scene", "gpu_available", "InputError", "SimulationDiverged", "SolverError",
           "DeviceError", "Shape", "Sphere", "Box", "Cylinder", "Capsule", "Cone", "Ellipsoid", "Hull", "Plane",
           "ces", "DeviceArray"]
__version__ = "0.1.0"


def gpu_available():
    """(True, device name) when the GPU backend can run here, else (False, why)."""
    return _dvisim.gpu_available()


def _json_value(v, key):
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, (list, tuple, np.ndarray)):
        return [_json_value(x, key) for x in v]
    if isinstance(v, float) and not math.isfinite(v):
        raise InputError(f"dvisim.System: settings.{key}: expected a finite number, got {v!r}")
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    raise InputError(f"dvisim.System: settings.{key}: expected a number, a string or a list, got {type(v).__name__}")


def _float_array(value, shape, what, allow_scalar=False):
    """value as a C-contiguous float64 array of `shape` (a scalar broadcast when allowed); InputError otherwise."""
    try:
        if isinstance(value, (str, bytes)) or np.iscomplexobj(value):
            raise TypeError
        a = np.asarray(value)
        if a.dtype.kind not in "iuf":
            raise TypeError
        a = a.astype(np.float64, copy=False)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected an array of numbers of shape {shape}, got {type(value).__name__}"
                         + (f" of {np.asarray(value).dtype}" if isinstance(value, np.ndarray) else "")) from None
    if allow_scalar and a.ndim == 0:
        a = np.full(shape, float(a))
    if a.shape != tuple(shape):
        raise InputError(f"{what}: expected shape {tuple(shape)}, got {a.shape}")
    bad = np.flatnonzero(~np.isfinite(a.reshape(len(a), -1) if a.ndim else a.reshape(1, 1)).all(axis=1))
    if bad.size:
        raise InputError(f"{what}: entry {int(bad[0])} is not finite")
    return np.ascontiguousarray(a)


def _material(friction, restitution, rolling_friction, spinning_friction):
    m = _float_array([friction, restitution, rolling_friction, spinning_friction], (4,),
                     "friction, restitution, rolling_friction, spinning_friction")
    for name, v in zip(("friction", "restitution", "rolling_friction", "spinning_friction"), m):
        if v < 0:
            raise InputError(f"{name}: must be >= 0, got {v!r}")
    return m


def _state_view(name, doc):
    """The read-only System property `name`: the engine's state array of that name (see the property's doc)."""
    return property(lambda self: getattr(self._s, name), doc=doc)


class DeviceArray:
    """A GPU array of the engine's state (N, k) exposed through __cuda_array_interface__ (version 3), so CuPy,
    PyTorch and Numba read it in place: cupy.asarray(a), torch.as_tensor(a, device="cuda"). Valid until the next
    change of the body count; it keeps the System alive."""

    def __init__(self, owner, pointer, count, cols, itemsize, stream):
        self._owner = owner
        self.shape = (int(count), int(cols))
        typestr = "<f8" if itemsize == 8 else "<f4"
        self.__cuda_array_interface__ = {"shape": self.shape, "typestr": typestr, "data": (int(pointer), False),
                                         "strides": None, "version": 3,
                                         "stream": int(stream) if stream else None}


class System:
    """A DVI system: bodies, their state as numpy arrays, steps.

    System(backend="auto", dt=1e-3, solver="apgd", iterations=None, max_iterations=None, tolerance=None,
           threads=0, gravity=(0, -9.81, 0), **settings)

    backend: "auto" (gpu where a device is usable, else cpu), "cpu" or "gpu". The other keywords are the keys of a
    scene's "settings" object (docs/SCENES.md; envelope_rel, friction_combine, warm_start, collision, ...), with
    the same defaults and the same checks: `iterations` alone is a fixed count, else the solve stops at
    `tolerance` (0.15) or after `max_iterations` (1000).
    """

    def __init__(self, backend="auto", dt=None, solver=None, iterations=None, max_iterations=None, tolerance=None,
                 threads=None, gravity=None, _core=None, **settings):
        if _core is not None:
            self._s = _core
            return
        given = dict(dt=dt, solver=solver, iterations=iterations, max_iterations=max_iterations, tolerance=tolerance,
                     threads=threads, gravity=gravity)
        given.update(settings)
        doc = {k: _json_value(v, k) for k, v in given.items() if v is not None}
        if not isinstance(backend, str):
            raise InputError(f"backend: expected auto, cpu or gpu, got {backend!r}")
        self._s = _dvisim._System(json.dumps(doc), backend)

    # ---- bodies ----
    def add_body(self, shapes, position=(0, 0, 0), rotation=(1, 0, 0, 0), velocity=(0, 0, 0),
                 angular_velocity=(0, 0, 0), mass=None, density=None, inertia=None, friction=0.5, restitution=0.0,
                 rolling_friction=0.0, spinning_friction=0.0, fixed=False, kinematic=False, gravity=None):
        """Adds one body of one or more shapes (a compound); returns its id.

        A dynamic body needs mass and inertia (principal moments, body frame), or a density for a single shape with
        a closed form (sphere, box, cylinder, ellipsoid) centred at the body's origin. fixed: never moves;
        kinematic: moves with its velocity, unaffected by contacts. gravity: this body's own acceleration."""
        shapes = [shapes] if isinstance(shapes, Shape) else list(shapes) if isinstance(shapes, (list, tuple)) else None
        if not shapes or not all(isinstance(s, Shape) for s in shapes):
            raise InputError("add_body: shapes must be a dvisim shape or a non-empty list of them")
        if fixed and kinematic:
            raise InputError("add_body: a body is either fixed or kinematic, not both")
        flags = 1 if fixed else 2 if kinematic else 0
        if flags:
            m, inert = 0.0, np.ones(3)
        else:
            m, inert = self._mass_properties(shapes, mass, density, inertia)
        g = np.zeros(0) if gravity is None else _float_array(gravity, (3,), "gravity")
        return self._s._add_body([s._record() for s in shapes], _float_array(position, (3,), "position"),
                                 _float_array(rotation, (4,), "rotation"), _float_array(velocity, (3,), "velocity"),
                                 _float_array(angular_velocity, (3,), "angular_velocity"), float(m), inert,
                                 _material(friction, restitution, rolling_friction, spinning_friction), flags, g)

    @staticmethod
    def _mass_properties(shapes, mass, density, inertia):
        if mass is not None and density is not None:
            raise InputError("add_body: give mass or density, not both")
        single = len(shapes) == 1 and shapes[0].at_origin() and shapes[0].volume() is not None
        if density is not None:
            d = float(_float_array(density, (), "density"))
            if not d > 0:
                raise InputError(f"density: must be > 0, got {density!r}")
            if not single:
                raise InputError("add_body: density needs one sphere, box, cylinder or ellipsoid at the body's "
                                 "origin; give mass and inertia for other bodies")
            mass = d * shapes[0].volume()
        if mass is None:
            raise InputError("add_body: a dynamic body needs a mass or a density (or fixed=True)")
        m = float(_float_array(mass, (), "mass"))
        if not m > 0:
            raise InputError(f"mass: must be > 0 for a dynamic body, got {mass!r}")
        if inertia is None:
            if not single:
                raise InputError("add_body: give the inertia (principal moments) of this body's shapes")
            inertia = [m * i for i in shapes[0].unit_inertia()]
        return m, _float_array(inertia, (3,), "inertia")

    def add_spheres(self, positions, radii, density=None, mass=None, velocities=None, friction=0.5, restitution=0.0,
                    rolling_friction=0.0, spinning_friction=0.0, fixed=False):
        """Adds N spheres at positions (N, 3) with radii (N,) or one radius; returns their ids (N,) int32.
        Mass from density (kg/m^3) or given per sphere (N,) or for all; inertia 2/5 m r^2."""
        try:
            n = len(positions)
        except TypeError:
            raise InputError("add_spheres: positions must be an (N, 3) array") from None
        pos = _float_array(positions, (n, 3), "positions")
        r = _float_array(radii, (n,), "radii", allow_scalar=True)
        if n and not np.all(r > 0):
            raise InputError(f"radii: must be > 0, got {r[np.argmin(r)]!r} for sphere {int(np.argmin(r))}")
        if mass is not None and density is not None:
            raise InputError("add_spheres: give mass or density, not both")
        if fixed:
            m = np.zeros(n)
        elif density is not None:
            d = float(_float_array(density, (), "density"))
            if not d > 0:
                raise InputError(f"density: must be > 0, got {density!r}")
            m = d * 4.0 / 3.0 * math.pi * r ** 3
        elif mass is not None:
            m = _float_array(mass, (n,), "mass", allow_scalar=True)
            if n and not np.all(m > 0):
                raise InputError(f"mass: must be > 0, got {m[np.argmin(m)]!r} for sphere {int(np.argmin(m))}")
        else:
            raise InputError("add_spheres: give a density or masses (or fixed=True)")
        vel = np.zeros((n, 3)) if velocities is None else _float_array(velocities, (n, 3), "velocities")
        return self._s._add_spheres(pos, r, np.ascontiguousarray(m, dtype=np.float64), vel,
                                    _material(friction, restitution, rolling_friction, spinning_friction),
                                    1 if fixed else 0)

    def add_mesh(self, vertices, triangles, position=(0, 0, 0), rotation=(1, 0, 0, 0), friction=0.5,
                 restitution=0.0):
        """Adds a fixed body of triangles: vertices (V, 3), triangles (T, 3) of vertex indices. Returns its id."""
        try:
            v_len = len(vertices)
            t_arr = np.asarray(triangles)
        except TypeError:
            raise InputError("add_mesh: vertices must be (V, 3) and triangles (T, 3)") from None
        v = _float_array(vertices, (v_len, 3), "add_mesh vertices")
        if t_arr.dtype.kind not in "iu" or t_arr.ndim != 2 or t_arr.shape[1] != 3:
            raise InputError(f"add_mesh triangles: expected an integer array of shape (T, 3), got {t_arr.dtype} "
                             f"{t_arr.shape}")
        return self._s._add_mesh(v, np.ascontiguousarray(t_arr, dtype=np.int64), _float_array(position, (3,), "position"),
                                 _float_array(rotation, (4,), "rotation"), _material(friction, restitution, 0, 0))

    # ---- stepping ----
    def step(self, n=1):
        """n steps of dt, with the GIL released (other Python threads run meanwhile)."""
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)):
            raise InputError(f"step: the number of steps must be an integer, got {n!r}")
        self._s.step(int(n))

    def run(self, steps=None, frames=None, out=None):
        """Steps `steps` (default: the scene's settings) and returns the run summary (dict, the keys of `dvisim
        run`'s summary.json). With out: writes there summary.json, bodies.csv and `frames` ParaView frames
        (frames.pvd), as `dvisim run --out --frames`."""
        for name, v in (("steps", steps), ("frames", frames)):
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0):
                raise InputError(f"run: {name} must be an integer >= 0, got {v!r}")
        return self._s._run(-1 if steps is None else int(steps), -1 if frames is None else int(frames),
                            "" if out is None else os.fspath(out))

    def summary(self):
        """The run summary of the steps taken so far (dict)."""
        return self._s.summary()

    @property
    def stats(self):
        """The last step's statistics: contacts, iterations, residuals, penetration."""
        return self._s.last_stats()

    # ---- state ----
    positions = _state_view("positions", "Centres of mass (N, 3). On the cpu backend a writable view of the engine's "
                            "array (no copy).")
    rotations = _state_view("rotations", "Rotations (N, 4), unit quaternions w, x, y, z (body to world).")
    velocities = _state_view("velocities", "Velocities of the centres of mass (N, 3), m/s.")
    angular_velocities = _state_view("angular_velocities", "Angular velocities (N, 3), rad/s, in the world frame.")

    def set_state(self, positions=None, rotations=None, velocities=None, angular_velocities=None):
        """Writes whole state arrays (N, 3) / (N, 4) on any backend (a device backend re-uploads)."""
        self._s.set_state(positions, rotations, velocities, angular_velocities)

    def apply_forces(self, forces, torques=None):
        """Adds external forces (N, 3) (and torques) to the bodies for the next step only."""
        self._s.apply_forces(forces, torques)

    def add_force_field(self, fn):
        """fn(t, positions, velocities) -> forces (N, 3) or (forces, torques), called once per step with copies of
        the state; added to every body's force. An exception in fn ends step() with it."""
        if not callable(fn):
            raise InputError("add_force_field: expected a callable fn(t, positions, velocities)")
        self._s.add_force_field(fn)

    def contacts(self):
        """The last step's contacts as a structured array: body_a, body_b, point_a, point_b, normal (A to B),
        distance (negative: penetration), impulse (normal, two tangential; N s)."""
        return self._s.contacts()

    def device_arrays(self):
        """On the gpu backend: {"positions", "rotations", "velocities", "angular_velocities"} as DeviceArray
        (__cuda_array_interface__), read in place by CuPy/PyTorch/Numba. InputError on the cpu backend."""
        r = self._s.device_refs()
        if r is None:
            raise InputError(f"device_arrays: the {self.backend} backend keeps its state in host memory "
                             "(use positions, rotations, ...)")
        cols = {"positions": 3, "rotations": 4, "velocities": 3, "angular_velocities": 3}
        return {k: DeviceArray(self, r[k], r["count"], c, r["itemsize"], r["stream"]) for k, c in cols.items()}

    body_count = property(lambda self: self._s.body_count)
    time = property(lambda self: self._s.time)
    step_count = property(lambda self: self._s.step_count)
    dt = property(lambda self: self._s.dt)
    backend = property(lambda self: self._s.backend)
    device = property(lambda self: self._s.device)

    def __len__(self):
        return self._s.body_count

    def __repr__(self):
        return f"<dvisim.System {self.backend}, {self.body_count} bodies, t = {self.time:g} s>"


def load_scene(path, overrides=None, backend="auto"):
    """A System from a .json or .bullet scene (the loader of `dvisim run`, the same messages). overrides: a dict
    {dotted.key: value} or a list of "KEY=VALUE" strings (`dvisim run --set`). System.run() then runs it for the
    scene's settings (steps or time, frames)."""
    sets = _override_list(overrides)
    if not isinstance(backend, str):
        raise InputError(f"backend: expected auto, cpu or gpu, got {backend!r}")
    return System(_core=_dvisim._load_scene(os.fspath(path), sets, backend))


def _text(v):
    if isinstance(v, np.generic):
        v = v.item()
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        if not math.isfinite(v):
            raise InputError(f"override value {v!r}: expected a finite number")
        return repr(v)
    if isinstance(v, (int, str)):
        return str(v)
    if isinstance(v, (list, tuple)):
        return json.dumps([_json_value(x, "override") for x in v])
    raise InputError(f"override value {v!r}: expected a number, a string or a list")


def _override_list(overrides):
    if overrides is None:
        return []
    if isinstance(overrides, dict):
        return [f"{k}={_text(v)}" for k, v in overrides.items()]
    if isinstance(overrides, (list, tuple)) and all(isinstance(s, str) for s in overrides):
        return list(overrides)
    raise InputError("overrides: expected a dict {key: value} or a list of \"KEY=VALUE\" strings")


from . import ces  # noqa: E402  (ces uses the helpers above)
