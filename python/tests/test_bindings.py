"""The bindings against the Rust results, numpy shapes and dtypes, errors, pickling, per-step
controls, the GIL and recordings."""

import json
import pickle
import shutil
import subprocess
import threading
import time

import numpy as np
import pytest

import powderlab
from conftest import ROOT, TINY

# Short horizons keep the central differences of `gradcheck` cheap; the tiny scene's spoon is
# already in the powder by then.
STEPS = 30


def test_loss_and_skill_gradient_are_gradchecks_bits(cli, tiny):
    out = subprocess.run(
        [str(cli), "gradcheck", str(TINY), "--params", "skill", "--steps", str(STEPS), "--json"],
        check=True, capture_output=True, text=True,
    ).stdout
    report = json.loads(out)
    r = powderlab.rollout(tiny, grad=True, steps=STEPS)
    assert r["loss"] == report["loss"]
    adjoint = [row["adjoint"] for row in report["rows"] if ".theta[" in row["parameter"]]
    assert len(adjoint) == 5
    assert r["grad_theta"].tolist() == adjoint


def test_same_bits_for_any_thread_count(tiny):
    one = powderlab.rollout(tiny, theta=[0.1, -0.2, 0.3, 0.0, 0.5], grad=True, steps=STEPS, threads=1)
    two = powderlab.rollout(tiny, theta=[0.1, -0.2, 0.3, 0.0, 0.5], grad=True, steps=STEPS, threads=2)
    for key in ("loss", "indicator", "transported"):
        assert one[key] == two[key]
    for key in ("positions", "velocities", "grad_theta", "grad_x0", "grad_v0", "grad_gravity"):
        assert np.array_equal(one[key], two[key]), key


def test_positions_are_the_cli_final_state(cli, tiny, tmp_path):
    ply = tmp_path / "cli.ply"
    subprocess.run(
        [str(cli), "simulate", str(TINY), "--steps", "12", "--save-state", str(ply)],
        check=True, capture_output=True,
    )
    sim = powderlab.Simulation(tiny)
    sim.step(12)
    mine = tmp_path / "py.ply"
    sim.save_ply(mine)
    assert mine.read_bytes() == ply.read_bytes()
    body = ply.read_bytes()
    data = np.frombuffer(body[body.index(b"end_header\n") + 11:], dtype="<f8").reshape(-1, 6)
    assert np.array_equal(sim.positions(), data[:, :3])
    assert np.array_equal(sim.velocities(), data[:, 3:])


def test_shapes_and_dtypes(tiny):
    sim = powderlab.Simulation(tiny, threads=1)
    n = sim.particle_count
    for a in (sim.positions(), sim.velocities()):
        assert a.shape == (n, 3) and a.dtype == np.float64 and a.flags.c_contiguous
    assert sim.body_ranges() == {"powder": (0, n)}
    t, q = sim.tool_pose("spoon")
    assert t.shape == (3,) and q.shape == (4,) and t.dtype == q.dtype == np.float64
    assert abs(np.linalg.norm(q) - 1.0) < 1e-12
    r = powderlab.rollout(tiny, grad=True, steps=5)
    assert r["positions"].shape == (n, 3) and r["grad_x0"].shape == (n, 3)
    assert r["grad_v0"].shape == (n, 3) and r["grad_gravity"].shape == (3,)
    assert r["grad_theta"].shape == (5,) and r["grad_theta"].dtype == np.float64
    assert r["grad_controls"]["spoon"].shape[1] == 6
    assert set(r["grad_material"]["powder"]) >= {"friction_deg", "youngs_modulus", "poisson_ratio"}
    assert set(r["grad_friction"]) == {"source_cup", "target_cup", "spoon"}
    assert all(np.isfinite(v) for v in r["grad_material"]["powder"].values())


def test_a_bad_scene_raises_with_the_message():
    text = TINY.read_text().replace("friction_deg: 30.0", "friction_deg: 95.0")
    with pytest.raises(powderlab.SceneError) as e:
        powderlab.Scene.from_str(text, "bad.ron")
    msg = str(e.value)
    assert msg.startswith("bad.ron:") and "friction_deg" in msg and "95" in msg
    assert "\n" not in msg
    with pytest.raises(powderlab.SceneError, match="no_such.ron: cannot read the scene file"):
        powderlab.Scene.load("no_such.ron")
    with pytest.raises(powderlab.SceneError, match="unknown_field"):
        powderlab.Scene.from_str(TINY.read_text().replace("seed: 7,", "seed: 7, unknown_field: 1,"))
    assert issubclass(powderlab.SceneError, ValueError)


def test_bad_arguments_raise(tiny):
    with pytest.raises(powderlab.SceneError, match="theta"):
        powderlab.rollout(tiny, theta=[2.0, 0, 0, 0, 0])
    with pytest.raises(ValueError, match="threads = 0"):
        powderlab.Simulation(tiny, threads=0)
    with pytest.raises(powderlab.SceneError, match="no_such_param"):
        tiny.with_params({"no_such_param": 1.0})
    sim = powderlab.Simulation(tiny)
    with pytest.raises(ValueError, match="no tool of that name"):
        sim.set_controls("ladle", [0.0] * 6)
    with pytest.raises(ValueError, match="faster than"):
        sim.set_controls("spoon", [1.0, 0, 0, 0, 0, 0])


def test_pickle_round_trip_gives_the_same_rollout(tiny):
    back = pickle.loads(pickle.dumps(tiny))
    assert back == tiny
    a = powderlab.rollout(tiny, steps=10)
    b = powderlab.rollout(back, steps=10)
    assert a["loss"] == b["loss"] and np.array_equal(a["positions"], b["positions"])


def test_with_params_changes_the_run(tiny):
    slippery = tiny.with_params({"friction_deg": 20.0, "spoon.friction": 0.1})
    a = powderlab.rollout(tiny, steps=20)
    b = powderlab.rollout(slippery, steps=20)
    assert not np.array_equal(a["positions"], b["positions"])


def test_set_controls_moves_the_tool_by_the_control(tiny):
    sim = powderlab.Simulation(tiny)
    speed, radius = sim.tool_limit("spoon")
    assert speed > 0 and radius > 0
    u = np.array([0.5 * speed * tiny.dt, 0.0, 0.0, 0.0, 0.0, 0.0])
    t0, q0 = sim.tool_pose("spoon")
    sim.set_controls("spoon", np.stack([u, -u]))
    sim.step()
    t1, q1 = sim.tool_pose("spoon")
    assert np.allclose(t1 - t0, u[:3], atol=1e-15, rtol=1e-12)
    assert np.array_equal(q0, q1)
    sim.step()
    t2, _ = sim.tool_pose("spoon")
    assert np.allclose(t2, t0, atol=1e-15)


def test_controls_rollout_gives_the_control_gradient(tiny):
    steps = 8
    u = np.zeros((steps, 6))
    u[:, 1] = -0.001
    r = powderlab.rollout(tiny, controls=u, grad=True)
    assert r["steps"] == steps
    assert "grad_theta" not in r
    g = r["grad_controls"]["spoon"]
    assert g.shape == (steps, 6) and np.all(np.isfinite(g))


def test_the_gil_is_released_while_simulating(tiny):
    window = {}

    def run():
        window["start"] = time.perf_counter()
        powderlab.rollout(tiny, steps=60, threads=1)
        window["end"] = time.perf_counter()

    th = threading.Thread(target=run)
    ticks = []
    th.start()
    while th.is_alive():
        ticks.append(time.perf_counter())
    th.join()
    lo, hi = window["start"], window["end"]
    assert hi - lo > 0.1, "the rollout is too short to tell"
    inside = [t for t in ticks if lo + 0.02 < t < hi - 0.02]
    # Holding the GIL would leave this thread without a tick until the rollout returned.
    assert len(inside) > 1000


def test_recording_is_a_valid_rrd(tiny, tmp_path):
    path = tmp_path / "run.rrd"
    sim = powderlab.Simulation(tiny)
    sim.record(path)
    sim.step(3)
    assert not path.exists()
    assert sim.finish_recording() == str(path)
    assert path.stat().st_size > 0
    rerun = shutil.which("rerun")
    cmd = [rerun] if rerun else [__import__("sys").executable, "-m", "rerun"]
    subprocess.run(cmd + ["rrd", "verify", str(path)], check=True, capture_output=True)
