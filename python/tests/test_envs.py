"""The Gymnasium environments: the checker, seeding, and the rewards' meaning."""

import gymnasium as gym
import numpy as np
from gymnasium.utils.env_checker import check_env

import powderlab
import powderlab.envs  # registers the ids
from conftest import TINY

RANDOMIZE = {"friction_deg": (25.0, 35.0)}


def test_skill_env_passes_the_checker():
    env = gym.make("powderlab/SkillTransport-v0", scene=str(TINY), randomize=RANDOMIZE)
    check_env(env.unwrapped, skip_render_check=True)


def test_tool_control_env_passes_the_checker():
    for obs in ("heightfield", "particles"):
        env = gym.make("powderlab/ToolControl-v0", scene=str(TINY), obs=obs, max_steps=4,
                       randomize=RANDOMIZE)
        check_env(env.unwrapped, skip_render_check=True)


def test_skill_env_reward_is_the_rollouts_dose_error(tiny):
    env = powderlab.envs.SkillEnv(TINY)
    obs, _ = env.reset(seed=0)
    assert obs.tolist() == [tiny.task[1]]
    theta = np.array([0.3, 0.2, 0.0, 0.0, 0.3])
    _, reward, terminated, truncated, info = env.step(theta)
    r = powderlab.rollout(tiny, theta=theta.tolist())
    assert terminated and not truncated
    assert reward == -abs(r["indicator"]) and info["loss"] == r["loss"]


def test_seeding_gives_the_same_episode():
    def episode(seed):
        env = powderlab.envs.ToolControlEnv(TINY, max_steps=3, randomize=RANDOMIZE)
        obs, info = env.reset(seed=seed)
        rng = np.random.default_rng(seed)
        out = [obs["powder"], obs["params"]]
        done = False
        while not done:
            obs, reward, done, _, info = env.step(rng.uniform(-1, 1, 6))
            out += [obs["powder"], obs["tool"], np.array([reward])]
        return out, info

    a, ia = episode(5)
    b, ib = episode(5)
    c, _ = episode(6)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    assert ia == ib and "dose_error" in ia
    assert not np.array_equal(a[1], c[1]), "another seed draws another friction angle"
    assert 25.0 <= a[1][0] <= 35.0


def test_tool_control_actions_stay_within_the_substeps_speed():
    env = powderlab.envs.ToolControlEnv(TINY, max_steps=2)
    env.reset(seed=0)
    speed, radius = env.sim.tool_limit(env.tool)
    dt = env.base_scene.dt
    # The largest action in every component: set_controls would refuse it if it were faster
    # than the scene's own skill, so the step itself is part of the check.
    t0 = env.sim.tool_pose(env.tool)[0]
    env.step(np.ones(6))
    t1 = env.sim.tool_pose(env.tool)[0]
    # The tool moved by the whole translation the action asked for (the tiny scene's tool is
    # far from the box's faces), and that move used half the speed budget, as the scaling says.
    moved = np.linalg.norm(t1 - t0)
    assert abs(moved - 0.5 * speed * dt) < 1e-12 * max(1.0, speed * dt), (moved, speed * dt)
    # Its rotation's share: |r|·R is the other half.
    assert abs(np.linalg.norm(env._scale[3:]) * radius - 0.5 * speed * dt) < 1e-12
    env.step(-np.ones(6))
    t2 = env.sim.tool_pose(env.tool)[0]
    assert np.linalg.norm(t2 - t0) < 1e-12, "the opposite action brings the tool back"


def test_heightfield_sees_the_powder_in_the_source_cup(tiny):
    env = powderlab.envs.ToolControlEnv(TINY, grid=(12, 12))
    obs, _ = env.reset(seed=0)
    h = obs["powder"]
    assert h.shape == (12, 12) and h.max() > 0.0
    lo, hi = tiny.domain
    x = powderlab.Simulation(tiny).positions()
    assert abs(h.max() - (x[:, 1].max() - lo[1])) < 1e-15


def _coarse_weighing(tmp_path):
    """``vial_weighing`` at dx = 2 mm (5k grains instead of 37k), written to a file."""
    import pathlib

    root = pathlib.Path(__file__).resolve().parents[2]
    text = (root / "scenes" / "vial_weighing.ron").read_text()
    text = (
        text.replace("cells: (72, 48, 32)", "cells: (36, 24, 16)")
        .replace("dx: 0.001", "dx: 0.002")
        .replace("walls: (cells: 3", "walls: (cells: 2")
    )
    path = tmp_path / "coarse_weighing.ron"
    path.write_text(text)
    return path


def test_weighing_env_passes_the_checker_and_rewards_the_dose_error(tmp_path):
    scene = _coarse_weighing(tmp_path)
    env = gym.make("powderlab/Weighing-v0", scene=str(scene), max_steps=3, settle_steps=5,
                   randomize={"friction_deg": (25.0, 45.0)})
    check_env(env.unwrapped, skip_render_check=True)
    env = powderlab.envs.WeighingEnv(str(scene), max_steps=40, settle_steps=50)
    obs, info = env.reset(seed=1)
    assert 5.0 <= obs["target_mg"][0] <= 50.0 and abs(obs["reading_mg"][0]) < 1.0
    done = False
    while not done:
        obs, reward, done, _, info = env.step(np.array([1.0, 1.0]))
    # Tilted and tapped for 80 steps: powder reached the boat, and the reward is its error.
    assert info["delivered_mg"] > 0.0
    assert reward == -abs(info["delivered_mg"] - info["target_mg"])
