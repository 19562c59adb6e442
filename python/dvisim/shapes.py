"""Shapes of a dvisim body (System.add_body), each at a pose in the body frame.

Each shape knows its volume and its principal moments of inertia per unit mass about its centre, where closed forms
exist, so that a one-shape body can be given a density instead of a mass and inertia. The formulas are the solid
bodies' standard moments (e.g. Meriam & Kraige, Engineering Mechanics: Dynamics, 7th ed. (2012), Appendix D, Table
D/4); the canonical axis is y, as in the engine (src/chrono_like/system.h: makeCylinder, ...).
"""

import math

import numpy as np

from ._dvisim import InputError

_IDENTITY = (1.0, 0.0, 0.0, 0.0)


def _vector(value, n, what):
    try:
        if isinstance(value, (str, bytes)) or np.iscomplexobj(value):
            raise TypeError
        a = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected {n} numbers, got {value!r}") from None
    if a.shape != (n,):
        raise InputError(f"{what}: expected {n} numbers, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise InputError(f"{what}: expected finite numbers, got {a.tolist()}")
    return a


def _positive(value, what):
    try:
        if isinstance(value, (str, bytes, bool)):
            raise TypeError
        x = float(value)
    except (TypeError, ValueError):
        raise InputError(f"{what}: expected a number, got {value!r}") from None
    if not (math.isfinite(x) and x > 0):
        raise InputError(f"{what}: must be a finite number > 0, got {value!r}")
    return x


def _positive3(value, what):
    """Three finite numbers > 0 (a box's half extents, an ellipsoid's semi-axes) as a list."""
    return [_positive(x, what) for x in _vector(value, 3, what)]


class Shape:
    """A shape: its type, three dimensions and its pose (position, rotation w, x, y, z) in the body frame."""

    type = ""

    def __init__(self, dims, position=(0, 0, 0), rotation=_IDENTITY, points=None, margin=0.0):
        self.dims = tuple(float(d) for d in dims)
        self.position = _vector(position, 3, f"{self.type} position")
        self.rotation = _vector(rotation, 4, f"{self.type} rotation")
        self.points = points
        self.margin = float(margin)

    def _record(self):
        return (self.type, np.asarray(self.dims, dtype=np.float64), self.position, self.rotation, self.points,
                self.margin)

    def volume(self):
        return None

    def unit_inertia(self):
        """Principal moments of inertia per unit mass about the centre, in the shape frame (None: no closed form)."""
        return None

    def at_origin(self):
        return not np.any(self.position) and np.array_equal(self.rotation, _IDENTITY)


class Sphere(Shape):
    type = "sphere"

    def __init__(self, radius, position=(0, 0, 0), rotation=_IDENTITY):
        r = _positive(radius, "sphere radius")
        super().__init__((r, r, r), position, rotation)

    def volume(self):
        return 4.0 / 3.0 * math.pi * self.dims[0] ** 3

    def unit_inertia(self):
        return (0.4 * self.dims[0] ** 2,) * 3  # 2/5 r^2


class Box(Shape):
    type = "box"

    def __init__(self, half_extents, position=(0, 0, 0), rotation=_IDENTITY):
        super().__init__(_positive3(half_extents, "box half_extents"), position, rotation)

    def volume(self):
        a, b, c = self.dims
        return 8.0 * a * b * c

    def unit_inertia(self):
        a, b, c = self.dims  # 1/12 (w^2 + d^2) with w = 2a, ...
        return ((b * b + c * c) / 3.0, (a * a + c * c) / 3.0, (a * a + b * b) / 3.0)


class Cylinder(Shape):
    type = "cylinder"

    def __init__(self, radius, half_height, position=(0, 0, 0), rotation=_IDENTITY):
        super().__init__((_positive(radius, "cylinder radius"), _positive(half_height, "cylinder half_height"), 0.0),
                         position, rotation)

    def volume(self):
        r, h = self.dims[0], self.dims[1]
        return math.pi * r * r * 2.0 * h

    def unit_inertia(self):
        r, h = self.dims[0], self.dims[1]  # axis y: r^2 / 2; across: (3 r^2 + L^2) / 12, L = 2h
        across = (3.0 * r * r + 4.0 * h * h) / 12.0
        return (across, 0.5 * r * r, across)


class Capsule(Shape):
    type = "capsule"

    def __init__(self, radius, half_length, position=(0, 0, 0), rotation=_IDENTITY):
        super().__init__((_positive(radius, "capsule radius"), _positive(half_length, "capsule half_length"), 0.0),
                         position, rotation)


class Cone(Shape):
    type = "cone"

    def __init__(self, radius, height, position=(0, 0, 0), rotation=_IDENTITY):
        super().__init__((_positive(radius, "cone radius"), _positive(height, "cone height"), 0.0), position, rotation)


class Ellipsoid(Shape):
    type = "ellipsoid"

    def __init__(self, semi_axes, position=(0, 0, 0), rotation=_IDENTITY):
        super().__init__(_positive3(semi_axes, "ellipsoid semi_axes"), position, rotation)

    def volume(self):
        a, b, c = self.dims
        return 4.0 / 3.0 * math.pi * a * b * c

    def unit_inertia(self):
        a, b, c = self.dims  # (b^2 + c^2) / 5, ...
        return ((b * b + c * c) / 5.0, (a * a + c * c) / 5.0, (a * a + b * b) / 5.0)


class Hull(Shape):
    """The convex hull of points (M, 3), M >= 4, swept by a sphere of radius margin."""

    type = "hull"

    def __init__(self, points, margin=0.0, position=(0, 0, 0), rotation=_IDENTITY):
        try:
            if np.iscomplexobj(points):
                raise TypeError
            p = np.ascontiguousarray(points, dtype=np.float64)
        except (TypeError, ValueError):
            raise InputError("hull points: expected an (M, 3) array of numbers") from None
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] < 4:
            raise InputError(f"hull points: expected shape (M, 3) with M >= 4, got {p.shape}")
        if not np.all(np.isfinite(p)):
            raise InputError("hull points: expected finite numbers")
        if not (math.isfinite(float(margin)) and float(margin) >= 0):
            raise InputError(f"hull margin: must be a finite number >= 0, got {margin!r}")
        super().__init__((0.0, 0.0, 0.0), position, rotation, points=p, margin=margin)


class Plane(Shape):
    """The static half-space {x : dot(normal, x) <= d} (for a fixed body: the ground)."""

    type = "plane"

    def __init__(self, normal=(0, 1, 0), d=0.0):
        n = _vector(normal, 3, "plane normal")
        if not np.any(n):
            raise InputError("plane normal: must not be zero")
        super().__init__(n / np.linalg.norm(n), margin=float(_vector([d], 1, "plane d")[0]))
