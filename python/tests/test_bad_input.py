"""Bad input from Python: every case raises dvisim.InputError (a ValueError) with a one-line message naming the
problem, never crashes the interpreter, and leaves the System usable. Scene errors carry the CLI's message."""

import numpy as np
import pytest

import dvisim
from conftest import run_cli


def system_with_two():
    s = dvisim.System(backend="cpu")
    s.add_spheres([[0, 1, 0], [1, 1, 0]], 0.1, density=1000)
    return s


# (name, action on a System of two spheres, a fragment of the message)
CASES = [
    ("positions wrong shape", lambda s: s.add_spheres(np.zeros((3, 2)), 0.1, density=1), r"shape \(3, 3\)"),
    ("positions 1-d", lambda s: s.add_spheres(np.zeros(3), 0.1, density=1), r"shape \(3, 3\)"),
    ("positions NaN", lambda s: s.add_spheres([[0, np.nan, 0]], 0.1, density=1), "not finite"),
    ("positions inf", lambda s: s.add_spheres([[0, np.inf, 0]], 0.1, density=1), "not finite"),
    ("positions strings", lambda s: s.add_spheres([["a", "b", "c"]], 0.1, density=1), "numbers"),
    ("positions complex", lambda s: s.add_spheres(np.zeros((1, 3), complex), 0.1, density=1), "numbers"),
    ("positions objects", lambda s: s.add_spheres(np.array([[None, 1, 2]], dtype=object), 0.1, density=1),
     "numbers"),
    ("positions not a sequence", lambda s: s.add_spheres(5, 0.1, density=1), "positions"),
    ("radii count", lambda s: s.add_spheres(np.zeros((2, 3)), [0.1, 0.1, 0.1], density=1), r"shape \(2,\)"),
    ("radius negative", lambda s: s.add_spheres([[0, 0, 0]], -0.1, density=1), "radii: must be > 0"),
    ("radius zero", lambda s: s.add_spheres([[0, 0, 0]], 0.0, density=1), "radii: must be > 0"),
    ("density negative", lambda s: s.add_spheres([[0, 0, 0]], 0.1, density=-5), "density: must be > 0"),
    ("density NaN", lambda s: s.add_spheres([[0, 0, 0]], 0.1, density=float("nan")), "density"),
    ("mass and density", lambda s: s.add_spheres([[0, 0, 0]], 0.1, density=1, mass=1), "not both"),
    ("no mass", lambda s: s.add_spheres([[0, 0, 0]], 0.1), "density or masses"),
    ("friction negative", lambda s: s.add_spheres([[0, 0, 0]], 0.1, density=1, friction=-1), "friction"),
    ("velocities shape", lambda s: s.add_spheres([[0, 0, 0]], 0.1, density=1, velocities=[1, 2]), "velocities"),
    ("step negative", lambda s: s.step(-3), "must be >= 0"),
    ("step float", lambda s: s.step(1.5), "integer"),
    ("step string", lambda s: s.step("10"), "integer"),
    ("set_state shape", lambda s: s.set_state(positions=np.zeros((5, 3))), r"shape \(2, 3\)"),
    ("set_state NaN", lambda s: s.set_state(velocities=[[0, 0, 0], [np.nan, 0, 0]]), "body 1"),
    ("set_state rotations cols", lambda s: s.set_state(rotations=np.zeros((2, 3))), r"shape \(2, 4\)"),
    ("forces shape", lambda s: s.apply_forces(np.zeros((2, 2))), r"shape \(2, 3\)"),
    ("forces strings", lambda s: s.apply_forces("up"), "forces"),
    ("forces wrong dtype", lambda s: s.apply_forces(np.array([["x"] * 3] * 2)), "forces"),
    ("field not callable", lambda s: s.add_force_field(42), "callable"),
    ("box negative", lambda s: s.add_body(dvisim.Box((1, -1, 1)), density=1), "half_extents"),
    ("hull too few points", lambda s: s.add_body(dvisim.Hull(np.zeros((3, 3))), mass=1, inertia=(1, 1, 1)),
     "M >= 4"),
    ("body without shapes", lambda s: s.add_body([], mass=1), "shapes"),
    ("body shapes not shapes", lambda s: s.add_body(["sphere"], mass=1), "shapes"),
    ("compound by density", lambda s: s.add_body([dvisim.Sphere(1), dvisim.Sphere(1, position=(1, 0, 0))],
                                                 density=1), "mass and inertia"),
    ("fixed and kinematic", lambda s: s.add_body(dvisim.Sphere(1), fixed=True, kinematic=True), "not both"),
    ("rotation length", lambda s: s.add_body(dvisim.Sphere(1), rotation=(1, 0, 0), density=1), "rotation"),
    ("zero rotation", lambda s: s.add_body(dvisim.Sphere(1), rotation=(0, 0, 0, 0), density=1), "rotation"),
    ("mesh index out of range", lambda s: s.add_mesh(np.zeros((3, 3)), [[0, 1, 7]]), "vertex 7"),
    ("mesh float indices", lambda s: s.add_mesh(np.zeros((3, 3)), np.zeros((1, 3))), "integer"),
    ("mesh degenerate", lambda s: s.add_mesh(np.zeros((3, 3)), [[0, 1, 2]]), "nonzero area"),
    ("run frames without out", lambda s: s.run(steps=2, frames=2), "output directory"),
    ("run negative steps", lambda s: s.run(steps=-1), "steps"),
    ("device arrays on cpu", lambda s: s.device_arrays(), "host memory"),
]


@pytest.mark.parametrize("action, fragment", [c[1:] for c in CASES], ids=[c[0] for c in CASES])
def test_bad_input_raises_and_leaves_the_system_usable(action, fragment):
    s = system_with_two()
    with pytest.raises(dvisim.InputError, match=fragment) as e:
        action(s)
    assert isinstance(e.value, ValueError) and "\n" not in str(e.value)
    s.step(2)  # still usable
    assert s.body_count in (2, 3) and np.all(np.isfinite(s.positions))


SYSTEM_CASES = [
    ({"dt": -1.0}, "settings.dt"),
    ({"dt": float("nan")}, "settings.dt"),
    ({"solver": "newton"}, "settings.solver"),
    ({"iterations": -4}, "settings.iterations"),
    ({"threads": 1.5}, "settings.threads"),
    ({"gravity": [0, 1]}, "settings.gravity"),
    ({"no_such_setting": 1}, "no_such_setting"),
    ({"tolerance": "tight"}, "settings.tolerance"),
    ({"backend": "tpu"}, "backend"),
    ({"backend": 3}, "backend"),
]


@pytest.mark.parametrize("kwargs, fragment", SYSTEM_CASES, ids=[str(k) for k, _ in SYSTEM_CASES])
def test_bad_configuration_raises(kwargs, fragment):
    with pytest.raises(dvisim.InputError, match=fragment):
        dvisim.System(**kwargs)


def write(path, text):
    path.write_text(text)
    return path


SCENES = [
    ("missing file", lambda d: d / "nope.json"),
    ("unknown key", lambda d: write(d / "a.json", '{"bodies": [], "settings": {"dtt": 1}}')),
    ("bad json", lambda d: write(d / "b.json", '{"bodies": [')),
    ("negative mass", lambda d: write(d / "c.json", '{"bodies": [{"shape": {"type": "sphere", "radius": 1}, '
                                                   '"mass": -1}]}')),
    ("unknown extension", lambda d: write(d / "d.txt", "hello")),
    ("empty bullet file", lambda d: write(d / "e.bullet", "")),
]


@pytest.mark.parametrize("make", [m for _, m in SCENES], ids=[n for n, _ in SCENES])
def test_scene_errors_carry_the_cli_message(cli, tmp_path, make):
    path = make(tmp_path)
    r = run_cli(cli, "run", path, "--backend", "cpu", "--out", tmp_path / "out", check=False)
    assert r.returncode == 2
    line = r.stderr.strip().splitlines()[-1]
    assert line.startswith("dvisim: error: ")
    with pytest.raises(dvisim.InputError) as e:
        dvisim.load_scene(path, backend="cpu")
    assert str(e.value) == line[len("dvisim: error: "):]


def test_bad_override_carries_the_cli_message(cli, source, tmp_path):
    scene = source / "scenes" / "stack.json"
    r = run_cli(cli, "run", scene, "--set", "settings.dt=-1", "--out", tmp_path / "o", check=False)
    with pytest.raises(dvisim.InputError) as e:
        dvisim.load_scene(scene, {"settings.dt": -1}, backend="cpu")
    assert r.returncode == 2 and str(e.value) == r.stderr.strip().splitlines()[-1][len("dvisim: error: "):]


CES_CASES = [
    (dict(overrides={"electrode.voltage_kV": "high"}), "voltage_kV"),
    (dict(overrides={"no.such.key": 1}), "ces.no: unknown key"),
    (dict(duration=-1), "--time"),
    (dict(duration=0.1, steps=10), "mutually exclusive"),
    (dict(backend="bullet"), "bullet"),
    (dict(seed=1.5), "seed"),
    (dict(overrides=5), "overrides"),
]


@pytest.mark.parametrize("kwargs, fragment", CES_CASES, ids=[str(k) for k, _ in CES_CASES])
def test_bad_ces_input_raises(kwargs, fragment):
    with pytest.raises(dvisim.InputError, match=fragment):
        dvisim.ces.run(**kwargs)


@pytest.mark.skipif(dvisim.gpu_available()[0], reason="a GPU device is present")
def test_gpu_backend_without_a_device_is_input_error():
    with pytest.raises(dvisim.InputError, match="no usable GPU device"):
        dvisim.System(backend="gpu")
    with pytest.raises(dvisim.InputError, match="gpu"):
        dvisim.ces.run(backend="gpu", duration=0.01)
