"""CMA-ES over the skill parameters Θ with each generation's rollouts run as Ray tasks.

    python python/examples/cma_on_ray.py scenes/powder_transport.ron --budget 24
    python python/examples/cma_on_ray.py scenes/powder_transport.ron --address auto   # a cluster

The objective is the dose error |indicator| (grams for the shipped scenes). The optimiser is
the `cma` package (pip install cma); its population is evaluated by
`powderlab.distributed.map_rollouts`, one rollout per Ray task.
"""

import argparse
import time

import cma
import numpy as np

import powderlab
from powderlab.distributed import map_rollouts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene")
    ap.add_argument("--budget", type=int, default=24, help="rollouts in all")
    ap.add_argument("--popsize", type=int, default=4)
    ap.add_argument("--sigma", type=float, default=0.3, help="initial step in Θ's [-1, 1] units")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--address", default=None, help='"auto" joins a cluster started with `ray start`')
    ap.add_argument("--num-cpus", type=int, default=None, help="CPUs of a local Ray (default: all)")
    a = ap.parse_args()

    scene = powderlab.Scene.load(a.scene)
    if scene.theta is None or scene.task is None:
        raise SystemExit(f"{a.scene}: needs a tool with a Skill control and a task")
    unit = scene.task[2]
    es = cma.CMAEvolutionStrategy(
        scene.theta, a.sigma,
        {"bounds": [-1.0, 1.0], "popsize": a.popsize, "seed": a.seed, "verbose": -9},
    )
    init = {} if a.address else {"num_cpus": a.num_cpus, "include_dashboard": False}
    best, best_theta, used, t0 = np.inf, None, 0, time.perf_counter()
    while used < a.budget:
        thetas = es.ask()[: a.budget - used]
        results = map_rollouts(scene, [t.tolist() for t in thetas], address=a.address, **init)
        errors = [abs(r["indicator"]) for r in results]
        used += len(thetas)
        if len(thetas) == es.popsize:
            es.tell(thetas, errors)
        k = int(np.argmin(errors))
        if errors[k] < best:
            best, best_theta = errors[k], thetas[k]
        print(f"{used:4d} rollouts  {time.perf_counter() - t0:7.1f} s  "
              f"generation best {min(errors):.3f} {unit}  best so far {best:.3f} {unit}")
    print(f"best dose error {best:.3f} {unit} at Θ = {np.round(best_theta, 4).tolist()}")


if __name__ == "__main__":
    main()
