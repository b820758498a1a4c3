"""powderlab: differentiable simulation of powders for robot skill learning.

The simulator is Rust (MLS-MPM with Drucker-Prager sand and a checkpointed adjoint); this
package binds it. Every number is the Rust library's: the same scene and parameters give the
same bits here as in ``powderlab`` on the command line, for any thread count.

Quick start::

    import powderlab
    scene = powderlab.Scene.shipped("powder_transport")  # or Scene.load("my_scene.ron")
    r = powderlab.rollout(scene, grad=True)
    print(r["loss"], r["indicator"], r["grad_theta"])

Submodules: ``powderlab.envs`` (Gymnasium environments, needs ``gymnasium``) and
``powderlab.distributed`` (rollouts as Ray tasks, needs ``ray``). ``powderlab.scenes()`` lists
the scenes shipped inside the package.
"""

from ._powderlab import (
    Scene,
    SceneError,
    Simulation,
    SimulationError,
    rollout,
    scenes,
    version,
)

__all__ = ["Scene", "SceneError", "Simulation", "SimulationError", "rollout", "scenes", "version"]
__version__ = version()
