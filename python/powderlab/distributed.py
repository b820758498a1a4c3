"""Rollouts as Ray tasks, over the cores of one machine or the machines of a cluster (needs
``ray``).

On one machine::

    from powderlab.distributed import map_rollouts
    results = map_rollouts(scene, thetas)            # starts a local Ray if none is running

On a cluster started with ``ray start --head`` on one machine and
``ray start --address=HEAD:6379`` on the others::

    results = map_rollouts(scene, thetas, address="auto")

``map_dataset`` makes a policy's dataset (``powderlab policy dataset``) with one task per
randomised scene, into the same files as the command.

Each task runs one rollout with ``threads`` worker threads (1 by default: Ray spreads the
tasks over the cores). The results are bitwise those of calling ``powderlab.rollout`` one by
one: the simulator gives the same bits for any thread count. A task whose worker dies (killed,
out of memory, a machine lost) is run again by Ray, up to ``max_retries`` times; a rollout has
no side effects, so a retried task returns the same result.
"""

from __future__ import annotations

import os
import signal
from pathlib import Path
from typing import Any, Dict, List, Optional, Sequence, Union

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


def _dataset_scene(scene: Scene, config: str, k: int, threads: int) -> str:
    from ._powderlab import policy_dataset_scene

    return policy_dataset_scene(scene, config, k, threads)


def _write_atomic(path: Path, text: str) -> None:
    tmp = path.with_name(path.name + ".partial")
    tmp.write_text(text)
    os.replace(tmp, path)


def map_dataset(
    scene: Scene,
    dir: Union[str, Path],
    scenes: int = 160,
    budget: int = 10,
    augment: int = 2,
    augment_steps: int = 1,
    perturb: float = 0.1,
    seed: int = 0,
    address: Optional[str] = None,
    threads: int = 1,
    max_retries: int = 3,
    **ray_init: Any,
) -> str:
    """A policy dataset of ``scene`` (a scene with a ``randomize`` section) in ``dir``, one Ray
    task per randomised scene; returns the path of ``dir/dataset.safetensors``.

    The arguments are ``powderlab policy dataset``'s options, and the files are the command's:
    each scene's ``scene-K.json`` is written (atomically) as its task finishes, so a killed run
    resumes with the scenes still missing, and the command run on the same folder with the
    same options finds every scene done. A scene is computed the same way wherever it runs, so
    the files do not depend on how the tasks were spread.
    """
    import ray

    from ._powderlab import (
        policy_dataset_claim,
        policy_dataset_config,
        policy_dataset_scene_file,
        policy_dataset_write,
    )

    config = policy_dataset_config(scene, scenes, budget, augment, augment_steps, perturb, seed)
    folder = Path(dir)
    policy_dataset_claim(str(folder), config)
    missing = [k for k in range(scenes) if not Path(policy_dataset_scene_file(str(folder), k)).exists()]
    if missing:
        if not ray.is_initialized():
            ray.init(address=address, **ray_init)
        task = ray.remote(_dataset_scene).options(num_cpus=threads, max_retries=max_retries)
        scene_ref = ray.put(scene)
        pending = {task.remote(scene_ref, config, k, threads): k for k in missing}
        while pending:
            done, _ = ray.wait(list(pending), num_returns=1)
            for ref in done:
                k = pending.pop(ref)
                _write_atomic(Path(policy_dataset_scene_file(str(folder), k)), ray.get(ref))
    return policy_dataset_write(scene, config, str(folder))
