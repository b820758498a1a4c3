"""Rollouts as Ray tasks on a local 2-CPU cluster: the same bits as one by one, and a killed
worker's task retried with nothing lost."""

import numpy as np
import pytest

import ray

import powderlab
from powderlab.distributed import FAULT_ENV, map_rollouts

THETAS = [[0.3, 0.2, 0.0, 0.0, 0.3], [-0.5, 0.5, 0.2, -0.3, 0.8], [0.0] * 5, [0.9, -0.9, 0.5, 0.5, -0.2]]
STEPS = 40


def _same(a, b):
    assert a["loss"] == b["loss"] and a["indicator"] == b["indicator"]
    assert np.array_equal(a["positions"], b["positions"])
    assert np.array_equal(a["velocities"], b["velocities"])


@pytest.fixture
def sequential(tiny):
    return [powderlab.rollout(tiny, theta=t, steps=STEPS, threads=1) for t in THETAS]


def test_ray_rollouts_match_the_sequential_run(tiny, sequential):
    try:
        out = map_rollouts(tiny, THETAS, steps=STEPS, num_cpus=2, include_dashboard=False)
    finally:
        ray.shutdown()
    assert len(out) == 4
    for a, b in zip(out, sequential):
        _same(a, b)


def test_a_killed_worker_is_retried_and_nothing_is_lost(tiny, sequential, tmp_path):
    marker = tmp_path / "killed"
    try:
        out = map_rollouts(
            tiny, THETAS, steps=STEPS, num_cpus=2, include_dashboard=False,
            runtime_env={"env_vars": {FAULT_ENV: str(marker)}},
        )
    finally:
        ray.shutdown()
    assert marker.exists(), "no worker was killed: the test proved nothing"
    assert len(out) == 4
    for a, b in zip(out, sequential):
        _same(a, b)
