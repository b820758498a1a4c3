"""Rollouts as Ray tasks, over the cores of one machine or the machines of a cluster (needs
``ray``).

On one machine::

    from powderlab.distributed import map_rollouts
    results = map_rollouts(scene, thetas)            # starts a local Ray if none is running

On a cluster started with ``ray start --head`` on one machine and
``ray start --address=HEAD:6379`` on the others::

    results = map_rollouts(scene, thetas, address="auto")

Each task runs one rollout with ``threads`` worker threads (1 by default: Ray spreads the
tasks over the cores). The results are bitwise those of calling ``powderlab.rollout`` one by
one: the simulator gives the same bits for any thread count. A task whose worker dies (killed,
out of memory, a machine lost) is run again by Ray, up to ``max_retries`` times; a rollout has
no side effects, so a retried task returns the same result.
"""

from __future__ import annotations

import os
import signal
from typing import Any, Dict, List, Optional, Sequence

from . import Scene, rollout

# Fault injection for the tests: when this names a file that does not exist yet, the first task
# to finish its rollout creates it and kills its own worker before returning, so that Ray must
# retry the task on another worker.
FAULT_ENV = "POWDERLAB_FAULT_KILL_ONCE"

_remote = None


def _run(scene: Scene, theta, grad: bool, steps: Optional[int], threads: int) -> Dict[str, Any]:
    r = rollout(scene, theta=None if theta is None else list(theta), grad=grad, steps=steps, threads=threads)
    marker = os.environ.get(FAULT_ENV)
    if marker:
        try:
            os.close(os.open(marker, os.O_CREAT | os.O_EXCL | os.O_WRONLY))
        except FileExistsError:
            pass
        else:
            os.kill(os.getpid(), signal.SIGKILL)
    return r


def _task():
    global _remote
    if _remote is None:
        import ray

        _remote = ray.remote(_run)
    return _remote


def map_rollouts(
    scene: Scene,
    thetas: Sequence[Optional[Sequence[float]]],
    address: Optional[str] = None,
    grad: bool = False,
    steps: Optional[int] = None,
    threads: int = 1,
    max_retries: int = 3,
    **ray_init: Any,
) -> List[Dict[str, Any]]:
    """One rollout per Θ in ``thetas`` (None for the scene's own), as Ray tasks, in order.

    ``address``: None starts a local Ray (or joins the one this process already started);
    ``"auto"`` joins a cluster started with ``ray start``. Extra keyword arguments go to
    ``ray.init`` (``num_cpus=2``, say). Each task asks Ray for ``threads`` CPUs.
    """
    import ray

    if not ray.is_initialized():
        ray.init(address=address, **ray_init)
    task = _task().options(num_cpus=threads, max_retries=max_retries)
    scene_ref = ray.put(scene)
    refs = [task.remote(scene_ref, theta, grad, steps, threads) for theta in thetas]
    return ray.get(refs)
