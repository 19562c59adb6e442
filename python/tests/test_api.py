"""The engine from Python: results checked against closed forms, the CLI, and conserved quantities."""

import json
import threading

import numpy as np
import pytest

import dvisim
from conftest import run_cli

G = 9.81


def test_defaults_are_the_cpp_defaults():
    s = dvisim.System(backend="cpu")
    assert s.dt == 1e-3 and s.backend == "cpu" and s.body_count == 0
    summ = s.summary()
    assert summ["solver"] == "apgd" and summ["tolerance"] == pytest.approx(0.15) and summ["max_iterations"] == 1000


def test_free_fall_is_symplectic_euler():
    # v_{k+1} = v_k - g h, y_{k+1} = y_k + h v_{k+1}  =>  y_n = y_0 - g h^2 n (n + 1) / 2 (no contact)
    s = dvisim.System(backend="cpu", dt=1e-3)
    ids = s.add_spheres([[0.0, 10.0, 0.0]], 0.1, density=1000)
    s.step(200)
    n, h = 200, 1e-3
    assert s.positions[ids[0], 1] == pytest.approx(10.0 - G * h * h * n * (n + 1) / 2, rel=0, abs=1e-12)
    assert s.velocities[ids[0], 1] == pytest.approx(-G * h * n, rel=0, abs=1e-12)
    assert s.step_count == 200 and s.time == pytest.approx(0.2)


def test_state_is_a_view_and_writes_reach_the_engine():
    s = dvisim.System(backend="cpu")
    s.add_spheres([[0, 5, 0], [2, 5, 0], [4, 5, 0]], 0.1, density=1000)
    p = s.positions
    assert np.shares_memory(p, s.positions) and p.flags.writeable
    p[1, 0] = 7.0  # a write through the view moves the body in the engine
    s.step(1)
    assert s.positions[1, 0] == 7.0 and s.positions[0, 0] == 0.0 and s.positions[2, 0] == 4.0


def test_positions_of_a_million_bodies_are_not_copied():
    n = 1_000_000
    s = dvisim.System(backend="cpu")
    s.add_spheres(np.column_stack([np.arange(n) * 0.03, np.zeros(n), np.zeros(n)]), 0.01, density=1000)
    a, b = s.positions, s.positions
    assert a.shape == (n, 3) and np.shares_memory(a, b)  # two reads, one memory: the engine's array
    assert a.base is not None and not a.flags.owndata
    a[n - 1, 2] = 3.5
    assert b[n - 1, 2] == 3.5
    assert s.rotations.shape == (n, 4) and np.shares_memory(s.rotations, s.rotations)


def test_a_live_view_blocks_a_growth_that_would_move_the_arrays():
    s = dvisim.System(backend="cpu")
    s.add_spheres([[0, 0, 0]], 0.1, density=1000)
    v = s.positions
    with pytest.raises(dvisim.InputError, match="numpy view"):
        s.add_spheres(np.zeros((1000, 3)), 0.1, density=1000)
    del v
    s.add_spheres(np.arange(3000).reshape(1000, 3), 0.1, density=1000)
    assert s.body_count == 1001


def resting_sphere(r=0.1, density=1000.0, **kw):
    s = dvisim.System(backend="cpu", **kw)
    ground = s.add_body(dvisim.Plane((0, 1, 0), 0.0), fixed=True)
    ball = int(s.add_spheres([[0, r, 0]], r, density=density)[0])
    return s, ground, ball, density * 4 / 3 * np.pi * r ** 3


def test_contact_impulse_carries_the_weight():
    s, ground, ball, m = resting_sphere()
    s.step(50)
    c = s.contacts()
    assert c.dtype.names == ("body_a", "body_b", "point_a", "point_b", "normal", "distance", "impulse")
    assert len(c) == 1 and {int(c["body_a"][0]), int(c["body_b"][0])} == {ground, ball}
    # at rest the normal impulse of a step balances gravity's: m g h (momentum balance)
    assert c["impulse"][0, 0] == pytest.approx(m * G * s.dt, rel=1e-3)
    assert abs(c["normal"][0, 1]) == pytest.approx(1.0)
    assert s.stats["contacts"] == 1


def test_applied_force_cancels_gravity_for_one_step():
    s = dvisim.System(backend="cpu")
    s.add_spheres([[0, 1, 0], [1, 1, 0]], 0.1, density=1000)
    m = 1000 * 4 / 3 * np.pi * 0.1 ** 3
    s.apply_forces([[0, m * G, 0], [0, 0, 0]])
    s.step(1)
    assert s.velocities[0, 1] == pytest.approx(0.0, abs=1e-12)  # held
    assert s.velocities[1, 1] == pytest.approx(-G * s.dt, abs=1e-12)  # fell
    s.step(1)  # forces last one step
    assert s.velocities[0, 1] == pytest.approx(-G * s.dt, abs=1e-12)


def test_force_field_callback_is_vectorised_and_called_every_step():
    s = dvisim.System(backend="cpu")
    s.add_spheres([[0, 1, 0], [2, 1, 0]], 0.1, density=1000)
    m = 1000 * 4 / 3 * np.pi * 0.1 ** 3
    times = []

    def hover(t, pos, vel):
        times.append(t)
        assert pos.shape == (2, 3) and vel.shape == (2, 3)
        f = np.zeros_like(pos)
        f[:, 1] = m * G  # weight cancelled: the bodies float
        return f

    s.add_force_field(hover)
    s.step(10)
    assert np.allclose(times, np.arange(10) * s.dt, rtol=0, atol=1e-12)
    assert np.allclose(s.positions[:, 1], 1.0, rtol=0, atol=1e-12)


def test_force_field_exception_ends_the_step_with_it():
    s = dvisim.System(backend="cpu")
    s.add_spheres([[0, 1, 0]], 0.1, density=1000)

    def bad(t, pos, vel):
        raise ZeroDivisionError("from the field")

    s.add_force_field(bad)
    with pytest.raises(ZeroDivisionError, match="from the field"):
        s.step(3)


def test_force_field_wrong_shape_is_input_error():
    s = dvisim.System(backend="cpu")
    s.add_spheres([[0, 1, 0]], 0.1, density=1000)
    s.add_force_field(lambda t, p, v: np.zeros((5, 3)))
    with pytest.raises(dvisim.InputError, match=r"shape \(1, 3\)"):
        s.step(1)


def test_box_by_density_rests_on_its_half_height():
    s = dvisim.System(backend="cpu")
    s.add_body(dvisim.Plane(), fixed=True)
    b = s.add_body(dvisim.Box((0.2, 0.1, 0.3)), position=(0, 0.1, 0), density=500)
    s.step(300)
    # resting: centre at the half height (to within the solver's penetration), not moving
    assert s.positions[b, 1] == pytest.approx(0.1, abs=2e-3)
    assert np.linalg.norm(s.velocities[b]) < 1e-2


def test_sphere_rests_on_a_triangle_mesh():
    s = dvisim.System(backend="cpu")
    verts = np.array([[-1, 0, -1], [1, 0, -1], [1, 0, 1], [-1, 0, 1]], dtype=float)
    s.add_mesh(verts, np.array([[0, 2, 1], [0, 3, 2]]))
    b = int(s.add_spheres([[0.1, 0.3, 0.2]], 0.1, density=1000)[0])
    s.step(400)
    assert s.positions[b, 1] == pytest.approx(0.1, abs=2e-3)


def test_compound_and_kinematic_bodies():
    s = dvisim.System(backend="cpu")
    dumbbell = [dvisim.Sphere(0.1, position=(-0.3, 0, 0)), dvisim.Sphere(0.1, position=(0.3, 0, 0)),
                dvisim.Capsule(0.02, 0.3, rotation=(np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)))]
    d = s.add_body(dumbbell, position=(0, 5, 0), mass=2.0, inertia=(0.01, 0.1, 0.1))
    k = s.add_body(dvisim.Box((1, 0.1, 1)), position=(5, 0, 0), velocity=(1, 0, 0), kinematic=True)
    e = s.add_body(dvisim.Ellipsoid((0.1, 0.2, 0.3)), position=(-5, 5, 0), density=800)
    s.step(100)
    assert s.positions[d, 1] == pytest.approx(5 - G * 1e-6 * 100 * 101 / 2, abs=1e-9)  # free fall
    assert s.positions[k, 0] == pytest.approx(5.1, abs=1e-12) and s.positions[k, 1] == 0  # prescribed motion
    assert s.positions[e, 1] == pytest.approx(s.positions[d, 1], abs=1e-12)


def test_step_releases_the_gil():
    s = dvisim.System(backend="cpu")
    s.add_spheres(np.random.default_rng(1).random((3000, 3)) * 2, 0.01, density=1000)
    ticks = []
    stop = threading.Event()

    def ticker():
        while not stop.is_set():
            ticks.append(1)
            stop.wait(0.001)

    t = threading.Thread(target=ticker)
    t.start()
    s.step(40)
    stop.set()
    t.join()
    assert len(ticks) > 5  # the other thread ran while the steps did


def test_scene_run_matches_the_cli_bit_for_bit(cli, source, tmp_path):
    scene = source / "scenes" / "stack.json"
    run_cli(cli, "run", scene, "--backend", "cpu", "--steps", "60", "--frames", "3", "--out", tmp_path / "cli")
    sim = dvisim.load_scene(scene, backend="cpu")
    summary = sim.run(steps=60, frames=3, out=tmp_path / "py")
    assert summary["steps"] == 60 and summary["frames"] == 3 and summary["status"] == "done"
    # the same engine, the same writer: identical final states and frames
    assert (tmp_path / "py" / "bodies.csv").read_bytes() == (tmp_path / "cli" / "bodies.csv").read_bytes()
    cli_frames = sorted(p.name for p in (tmp_path / "cli").iterdir() if p.suffix in (".vtp", ".pvd"))
    py_frames = sorted(p.name for p in (tmp_path / "py").iterdir() if p.suffix in (".vtp", ".pvd"))
    assert py_frames == cli_frames and len(cli_frames) == 4
    last = [n for n in cli_frames if n.endswith(".vtp")][-1]
    assert (tmp_path / "py" / last).read_bytes() == (tmp_path / "cli" / last).read_bytes()
    cli_summary = json.loads((tmp_path / "cli" / "summary.json").read_text())
    for key in ("bodies", "iterations_mean", "contacts_mean", "max_penetration", "stages"):
        assert summary[key] == cli_summary[key], key


def test_scene_overrides_as_dict_and_list(source):
    a = dvisim.load_scene(source / "scenes" / "stack.json", {"settings.dt": 5e-4}, backend="cpu")
    b = dvisim.load_scene(source / "scenes" / "stack.json", ["settings.dt=5e-4"], backend="cpu")
    assert a.dt == b.dt == 5e-4


def test_ctrl_c_ends_a_long_step_call_with_keyboard_interrupt():
    import os
    import signal
    import subprocess
    import sys
    code = ("import dvisim, numpy as np, sys\n"
            "s = dvisim.System(backend='cpu', threads=1)\n"
            "s.add_spheres(np.random.default_rng(0).random((2000, 3)), 0.01, density=1000)\n"
            "print('ready', flush=True)\n"
            "try:\n    s.step(10**7)\nexcept KeyboardInterrupt:\n"
            "    print('interrupted after', s.step_count, flush=True)\n"
            "s.step(1)\nprint('usable', s.step_count)\n")
    p = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True, env=dict(os.environ))
    assert p.stdout.readline().strip() == "ready"
    import time
    time.sleep(0.5)
    p.send_signal(signal.SIGINT)
    out, _ = p.communicate(timeout=30)
    assert p.returncode == 0 and "interrupted after" in out and "usable" in out
    n = int(out.split("interrupted after")[1].split()[0])
    assert 0 < n < 10**7 and f"usable {n + 1}" in out


def test_another_thread_may_not_touch_a_stepping_system():
    s = dvisim.System(backend="cpu")
    s.add_spheres(np.random.default_rng(2).random((2000, 3)) * 2, 0.01, density=1000)
    started = threading.Event()

    def field(t, pos, vel):
        started.set()
        return np.zeros_like(pos)

    s.add_force_field(field)
    t = threading.Thread(target=lambda: s.step(60))
    t.start()
    assert started.wait(30)
    with pytest.raises(RuntimeError, match="another thread"):
        s.add_spheres([[9, 9, 9]], 0.01, density=1000)
    t.join()
    assert s.step_count == 60 and s.body_count == 2000
