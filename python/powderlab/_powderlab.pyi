"""Type stubs of the compiled bindings (python/src/*.rs)."""

from os import PathLike
from typing import Dict, List, Optional, Sequence, Tuple, TypedDict, Union

import numpy as np
import numpy.typing as npt

_F64 = npt.NDArray[np.float64]
_Path = Union[str, PathLike[str]]

class SceneError(ValueError):
    """A scene the checks refuse: one line with file, line, column, field, value and remedy."""

class SimulationError(RuntimeError):
    """A run that stopped: a non-finite value (stage, particle, field) or an adjoint failure."""

class Scene:
    """A scene: parsed, every field checked."""

    @staticmethod
    def load(path: _Path) -> Scene:
        """Loads and checks a scene file (RON); raises SceneError on the first problem."""
    @staticmethod
    def shipped(name: str) -> Scene:
        """The shipped scene ``name`` (see ``scenes()``); raises SceneError listing them."""
    @staticmethod
    def resolve(path: _Path) -> Scene:
        """A scene file's path, or a shipped scene's bare name where no such file exists."""
    @staticmethod
    def from_str(text: str, name: str = "<string>") -> Scene:
        """Parses a scene from RON text; `name` stands for the file name in messages."""
    def to_ron(self) -> str:
        """The scene as RON text, every field written out."""
    @property
    def path(self) -> str: ...
    @property
    def dt(self) -> float:
        """Global step length (s)."""
    @property
    def domain(self) -> Tuple[List[float], List[float]]:
        """The grid's box (m): (lower corner, upper corner)."""
    @property
    def bodies(self) -> List[str]: ...
    @property
    def tools(self) -> List[str]: ...
    @property
    def theta(self) -> Optional[List[float]]:
        """Θ of the skill-driven tool, or None."""
    @property
    def task(self) -> Optional[Tuple[str, float, str]]:
        """(target cup, amount, unit "g" or "particles"), or None."""
    def with_theta(self, theta: Sequence[float]) -> Scene:
        """A checked copy with the skill tool's Θ replaced (five values in [-1, 1])."""
    def with_params(self, params: Dict[str, float]) -> Scene:
        """A checked copy with material parameters or `COLLIDER.friction` set by name."""
    def with_actions(self, actions: Union[_F64, Sequence[Sequence[float]]], tool: Optional[str] = None) -> Scene:
        """A checked copy whose tool follows (T, 6) per-step displacements."""

class Simulation:
    """A running simulation."""

    def __init__(self, scene: Scene, threads: Optional[int] = None) -> None: ...
    def step(self, n: int = 1) -> None:
        """Advances n global steps; raises SimulationError on a non-finite value."""
    @property
    def step_index(self) -> int: ...
    @property
    def time(self) -> float: ...
    @property
    def horizon(self) -> int: ...
    @property
    def substeps(self) -> int: ...
    @property
    def threads(self) -> int: ...
    @property
    def particle_count(self) -> int: ...
    def body_ranges(self) -> Dict[str, Tuple[int, int]]:
        """Each body's rows in positions() and velocities()."""
    def positions(self) -> _F64:
        """(N, 3) float64 particle positions (m), bodies in scene order."""
    def velocities(self) -> _F64:
        """(N, 3) float64 particle velocities (m/s)."""
    def tool_pose(self, name: str) -> Tuple[_F64, _F64]:
        """(position (3,), quaternion (4,) x, y, z, w) of a collider."""
    def balance_reading(self) -> Optional[float]:
        """The balance's display (mg), None without a balance."""
    def skill_phases(self, tool: str) -> List[int]:
        """Steps of the skill's six phases (descend, scoop, lift, transport, pour, settle)."""
    def tool_limit(self, tool: str) -> Tuple[float, float]:
        """(largest point speed m/s the controls may reach, bounding radius m)."""
    def set_controls(self, tool: str, controls: Union[_F64, Sequence[float], Sequence[Sequence[float]]]) -> None:
        """Per-step displacement(s) of a tool from the current step: (6,) or (k, 6)."""
    def score(self) -> Dict[str, float]:
        """loss, and with a task transported, indicator and dose_error, in the current state."""
    def save_ply(self, path: _Path) -> None:
        """Writes the particles as a binary PLY (x y z vx vy vz doubles), atomically."""
    def record(self, path: _Path) -> None:
        """Starts a Rerun recording: the state now and every later step."""
    def finish_recording(self) -> Optional[str]:
        """Completes the recording; returns its path."""

class RolloutResult(TypedDict, total=False):
    loss: Optional[float]
    indicator: Optional[float]
    transported: Optional[float]
    steps: int
    substeps: int
    positions: _F64
    velocities: _F64
    grad_theta: _F64
    grad_controls: Dict[str, _F64]
    grad_material: Dict[str, Dict[str, float]]
    grad_x0: _F64
    grad_v0: _F64
    grad_friction: Dict[str, float]
    grad_gravity: _F64

def rollout(
    scene: Scene,
    theta: Optional[Sequence[float]] = None,
    controls: Optional[Union[_F64, Sequence[Sequence[float]]]] = None,
    tool: Optional[str] = None,
    loss: bool = True,
    grad: bool = False,
    steps: Optional[int] = None,
    threads: Optional[int] = None,
    tape_budget_mb: Optional[int] = None,
) -> RolloutResult:
    """One rollout at Θ (or with a tool's (T, 6) controls), with the adjoint's gradients when
    grad=True. The GIL is released while it runs."""

def version() -> str: ...
def scenes() -> List[str]:
    """The names of the scenes shipped with the package, for ``Scene.shipped``."""

def policy_dataset_config(
    scene: Scene,
    scenes: int = 36,
    budget: int = 20,
    augment: int = 2,
    augment_steps: int = 1,
    perturb: float = 0.1,
    seed: int = 0,
) -> str:
    """The settings (JSON) of a policy dataset of ``scene``, as ``powderlab policy dataset``
    makes them."""

def policy_dataset_claim(dir: str, config: str) -> None:
    """Makes ``dir`` a folder of the dataset ``config`` (writes or checks its settings)."""

def policy_dataset_scene(scene: Scene, config: str, k: int, threads: int = 1) -> str:
    """Randomised scene ``k``'s samples, as the JSON the CLI keeps in ``scene-K.json``."""

def policy_dataset_scene_file(dir: str, k: int) -> str:
    """The path of scene ``k``'s file in ``dir``."""

def policy_dataset_write(scene: Scene, config: str, dir: str) -> str:
    """Gathers ``dir``'s scene files into ``dataset.safetensors``; returns its path."""
