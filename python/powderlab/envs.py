"""Gymnasium environments over powderlab scenes (needs ``gymnasium``).

Three ids are registered when this module is imported:

``powderlab/SkillTransport-v0``
    The seed paper's framing: one step per episode. The action is the skill's Θ in [-1, 1]^5
    (scoop depth, scoop angle, lift height, transport distance, pour angle); the episode is one
    rollout; the reward is minus the dose error in the task's unit (grams for the shipped
    scenes), or minus the scene's loss with ``reward="loss"``.

``powderlab/ToolControl-v0``
    Per-step control: the action is a 6-D displacement of the tool per global step
    (translation and rotation vector), scaled from [-1, 1] so that the tool never moves faster
    than the scene's own skill did (the speed the substeps were chosen for). The observation is
    a height field of the powder (``obs="heightfield"``, the default) or every particle's
    position (``obs="particles"``), with the tool's pose. The reward is sparse: minus the dose
    error at the last step, 0 before it.

``powderlab/Weighing-v0``
    Milligram weighing onto the scene's balance (``vial_weighing``, see ``powderlab weigh``):
    each reset draws a target (``target_mg``, 5-50 mg by default), and the spatula scoops and
    is carried over the boat by the scene's skill. The observation is what a weighing robot
    has: the balance's reading and the target (mg) and the spatula's pose; never the grains.
    The action is (tilt rate, tap) in [-1, 1]²: the spatula turns about ``axis`` by up to half
    the scene's speed budget per step, and a positive tap drops it by up to that much and lifts
    it back (an action is two steps, down and up). After ``max_steps`` actions the spatula
    turns back upright, the powder settles for a second, and the reward is minus the dose error
    in mg (an overshoot counts as much as a shortfall).

All three take ``randomize={"friction_deg": (25, 40), ...}``: each reset draws those parameters
uniformly from the episode's seed (any name ``Scene.with_params`` takes), and the observation
carries their values, so that a policy can be trained over randomised powders. The same seed
gives the same episode, bit for bit.
"""

from __future__ import annotations

import os
from typing import Any, Dict, Optional, Tuple, Union

import numpy as np
import gymnasium as gym
from gymnasium import spaces

from . import Scene, Simulation, rollout

SceneLike = Union[str, "os.PathLike[str]", Scene]

def resolve_scene(scene: SceneLike) -> Scene:
    """A Scene from a Scene, a path, or the name of a shipped scene (``"powder_transport"``,
    see ``powderlab.scenes()``): the shipped scenes are inside the package, so the defaults
    work from any folder. A file of that name in the working folder wins over a shipped one."""
    if isinstance(scene, Scene):
        return scene
    return Scene.resolve(os.fspath(scene))


def _pose_space(lo: np.ndarray, hi: np.ndarray) -> spaces.Box:
    """A tool's pose: its position inside the grid's box, then a unit quaternion."""
    return spaces.Box(
        np.concatenate([lo, -np.ones(4)]), np.concatenate([hi, np.ones(4)]), dtype=np.float64
    )


class _Randomized:
    """The domain randomisation shared by both environments."""

    def _setup_randomize(self, randomize: Optional[Dict[str, Tuple[float, float]]]) -> None:
        self.randomize = dict(sorted((randomize or {}).items()))
        for name, (lo, hi) in self.randomize.items():
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"randomize['{name}'] = ({lo}, {hi}): expected finite lo <= hi")
        # Fail now, not at the first reset, on a name the scene does not have.
        if self.randomize:
            self.base_scene.with_params({k: lo for k, (lo, _) in self.randomize.items()})
        self._params = np.array([lo for lo, _ in self.randomize.values()], dtype=np.float64)

    def _draw_scene(self) -> Scene:
        if not self.randomize:
            return self.base_scene
        lo = np.array([r[0] for r in self.randomize.values()])
        hi = np.array([r[1] for r in self.randomize.values()])
        self._params = lo + (hi - lo) * self.np_random.random(len(lo))
        return self.base_scene.with_params(dict(zip(self.randomize, self._params.tolist())))

    def _params_space(self) -> spaces.Box:
        """The randomised parameters' values, each within its range."""
        ranges = list(self.randomize.values())
        return spaces.Box(
            np.array([r[0] for r in ranges], dtype=np.float64),
            np.array([r[1] for r in ranges], dtype=np.float64),
            dtype=np.float64,
        )

    def _params_info(self) -> Dict[str, float]:
        return dict(zip(self.randomize, self._params.tolist()))


class SkillEnv(_Randomized, gym.Env):
    """One rollout per episode; the action is Θ (see the module docs)."""

    metadata = {"render_modes": []}

    def __init__(
        self,
        scene: SceneLike = "powder_transport",
        reward: str = "dose",
        randomize: Optional[Dict[str, Tuple[float, float]]] = None,
        threads: Optional[int] = None,
    ) -> None:
        self.base_scene = resolve_scene(scene)
        if self.base_scene.theta is None or self.base_scene.task is None:
            raise ValueError(
                f"{self.base_scene.path}: SkillEnv needs a scene with one Skill tool and a task"
            )
        if reward not in ("dose", "loss"):
            raise ValueError(f"reward = {reward!r}: expected 'dose' or 'loss'")
        self.reward_kind = reward
        self.threads = threads
        self._setup_randomize(randomize)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(5,), dtype=np.float64)
        # The task's target amount, then each randomised parameter.
        amount = self.base_scene.task[1]
        self.observation_space = spaces.Box(
            np.array([0.0] + [lo for lo, _ in self.randomize.values()], dtype=np.float64),
            np.array([amount] + [hi for _, hi in self.randomize.values()], dtype=np.float64),
            dtype=np.float64,
        )
        self._scene = self.base_scene

    def _obs(self) -> np.ndarray:
        return np.concatenate([[self.base_scene.task[1]], self._params]).astype(np.float64)

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        self._scene = self._draw_scene()
        return self._obs(), {"params": self._params_info()}

    def step(self, action):
        theta = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        r = rollout(self._scene, theta=theta.tolist(), threads=self.threads)
        dose_error = abs(r["indicator"])
        reward = -dose_error if self.reward_kind == "dose" else -r["loss"]
        info: Dict[str, Any] = {
            "loss": r["loss"],
            "indicator": r["indicator"],
            "transported": r["transported"],
            "dose_error": dose_error,
            "params": self._params_info(),
        }
        return self._obs(), float(reward), True, False, info


class ToolControlEnv(_Randomized, gym.Env):
    """Per-step 6-D control of the scene's tool (see the module docs)."""

    metadata = {"render_modes": []}

    def __init__(
        self,
        scene: SceneLike = "powder_transport",
        obs: str = "heightfield",
        grid: Tuple[int, int] = (16, 16),
        randomize: Optional[Dict[str, Tuple[float, float]]] = None,
        max_steps: Optional[int] = None,
        threads: Optional[int] = None,
    ) -> None:
        self.base_scene = resolve_scene(scene)
        if self.base_scene.task is None or not self.base_scene.tools:
            raise ValueError(f"{self.base_scene.path}: ToolControlEnv needs a tool and a task")
        if obs not in ("heightfield", "particles"):
            raise ValueError(f"obs = {obs!r}: expected 'heightfield' or 'particles'")
        self.obs_kind = obs
        self.grid = (int(grid[0]), int(grid[1]))
        self.threads = threads
        self.tool = self.base_scene.tools[0]
        self._setup_randomize(randomize)
        probe = Simulation(self.base_scene, threads=threads)
        self.max_steps = int(max_steps or probe.horizon)
        n = probe.particle_count
        speed, radius = probe.tool_limit(self.tool)
        if speed <= 0.0:
            raise ValueError(
                f"{self.base_scene.path}: tool '{self.tool}' does not move in the scene, so the "
                "substeps allow no motion; give it a control whose speed bounds the actions"
            )
        dt = self.base_scene.dt
        # Half the speed budget each to translation and rotation: |t|/dt + |r|·R/dt <= speed.
        self._scale = np.array(
            [0.5 * speed * dt / np.sqrt(3.0)] * 3 + [0.5 * speed * dt / (radius * np.sqrt(3.0))] * 3
        )
        lo, hi = self.base_scene.domain
        self._lo, self._hi = np.array(lo), np.array(hi)
        self.action_space = spaces.Box(-1.0, 1.0, shape=(6,), dtype=np.float64)
        if obs == "heightfield":
            powder = spaces.Box(0.0, float(hi[1] - lo[1]), shape=self.grid, dtype=np.float64)
        else:
            # The domain walls keep every particle inside the grid's box.
            powder = spaces.Box(
                np.tile(self._lo, (n, 1)), np.tile(self._hi, (n, 1)), dtype=np.float64
            )
        self.observation_space = spaces.Dict(
            {
                "powder": powder,
                # Position (kept inside the grid's box by `step`), then a unit quaternion.
                "tool": _pose_space(self._lo, self._hi),
                "params": self._params_space(),
            }
        )
        self.sim: Optional[Simulation] = None

    def heightfield(self, x: np.ndarray) -> np.ndarray:
        """The powder's top surface over the domain's x-z footprint: the highest particle
        above the floor in each cell, 0 where the cell is empty."""
        gx, gz = self.grid
        ix = np.clip(((x[:, 0] - self._lo[0]) / (self._hi[0] - self._lo[0]) * gx).astype(int), 0, gx - 1)
        iz = np.clip(((x[:, 2] - self._lo[2]) / (self._hi[2] - self._lo[2]) * gz).astype(int), 0, gz - 1)
        h = np.zeros(self.grid)
        np.maximum.at(h, (ix, iz), np.clip(x[:, 1] - self._lo[1], 0.0, None))
        return h

    def _obs(self) -> Dict[str, np.ndarray]:
        x = self.sim.positions()
        t, q = self.sim.tool_pose(self.tool)
        powder = self.heightfield(x) if self.obs_kind == "heightfield" else x
        return {"powder": powder, "tool": np.concatenate([t, q]), "params": self._params.copy()}

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        self.sim = Simulation(self._draw_scene(), threads=self.threads)
        return self._obs(), {"params": self._params_info()}

    def step(self, action):
        if self.sim is None:
            raise RuntimeError("step() before reset()")
        u = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0) * self._scale
        # Keep the tool's origin inside the grid's box.
        t, _ = self.sim.tool_pose(self.tool)
        u[:3] = np.clip(t + u[:3], self._lo, self._hi) - t
        self.sim.set_controls(self.tool, u.tolist())
        self.sim.step()
        done = self.sim.step_index >= self.max_steps
        info: Dict[str, Any] = {"params": self._params_info()}
        reward = 0.0
        if done:
            r = self.sim.score()
            info.update(r)
            reward = -r["dose_error"]
        return self._obs(), float(reward), done, False, info


class WeighingEnv(_Randomized, gym.Env):
    """Tilt and tap a spatula over a balance (see the module docs)."""

    metadata = {"render_modes": []}

    def __init__(
        self,
        scene: SceneLike = "vial_weighing",
        target_mg: Tuple[float, float] = (5.0, 50.0),
        randomize: Optional[Dict[str, Tuple[float, float]]] = None,
        axis: Tuple[float, float, float] = (0.0, 0.0, 1.0),
        max_steps: int = 300,
        settle_steps: int = 100,
        threads: Optional[int] = None,
    ) -> None:
        self.base_scene = resolve_scene(scene)
        if not self.base_scene.tools:
            raise ValueError(f"{self.base_scene.path}: WeighingEnv needs a spatula (a skill tool)")
        lo_t, hi_t = float(target_mg[0]), float(target_mg[1])
        if not (np.isfinite(lo_t) and np.isfinite(hi_t) and 0.0 <= lo_t <= hi_t):
            raise ValueError(f"target_mg = {target_mg}: expected 0 <= lo <= hi, finite")
        if max_steps < 1 or settle_steps < 0:
            raise ValueError(f"max_steps = {max_steps}, settle_steps = {settle_steps}: expected >= 1 and >= 0")
        a = np.asarray(axis, dtype=np.float64)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) == 0.0:
            raise ValueError(f"axis = {axis}: expected a non-zero 3-vector")
        self.axis = a / np.linalg.norm(a)
        self.target_range = (lo_t, hi_t)
        self.max_steps, self.settle_steps, self.threads = int(max_steps), int(settle_steps), threads
        self.tool = self.base_scene.tools[0]
        self._setup_randomize(randomize)
        probe = Simulation(self.base_scene, threads=threads)
        if probe.balance_reading() is None:
            raise ValueError(f"{self.base_scene.path}: WeighingEnv needs a scene with a balance")
        self._phases = probe.skill_phases(self.tool)
        speed, radius = probe.tool_limit(self.tool)
        dt = self.base_scene.dt
        # Half the speed budget each to the turn and the tap.
        self._turn = 0.5 * speed * dt / radius
        self._tap = 0.5 * speed * dt
        lo, hi = self.base_scene.domain
        self.action_space = spaces.Box(-1.0, 1.0, shape=(2,), dtype=np.float64)
        self.observation_space = spaces.Dict(
            {
                "reading_mg": spaces.Box(-1e6, 1e6, shape=(1,), dtype=np.float64),
                "target_mg": spaces.Box(lo_t, hi_t, shape=(1,), dtype=np.float64),
                "tool": _pose_space(np.array(lo), np.array(hi)),
                "params": self._params_space(),
            }
        )
        self.sim: Optional[Simulation] = None

    def _obs(self) -> Dict[str, np.ndarray]:
        t, q = self.sim.tool_pose(self.tool)
        return {
            "reading_mg": np.array([self.sim.balance_reading()]),
            "target_mg": np.array([self.target]),
            "tool": np.concatenate([t, q]),
            "params": self._params.copy(),
        }

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        super().reset(seed=seed)
        scene = self._draw_scene()
        lo, hi = self.target_range
        self.target = float(lo + (hi - lo) * self.np_random.random())
        self.sim = Simulation(scene, threads=self.threads)
        # The skill's descent, scoop, lift and carry, as the scene's own controls give them.
        self.sim.step(int(sum(self._phases[:4])))
        self.tilt, self.steps = 0.0, 0
        return self._obs(), {"params": self._params_info(), "target_mg": self.target}

    def _turn_row(self, w: float, y: float = 0.0) -> list:
        r = self.axis * w
        return [0.0, y, 0.0, float(r[0]), float(r[1]), float(r[2])]

    def step(self, action):
        if self.sim is None:
            raise RuntimeError("step() before reset()")
        a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
        # Half the turn on each of the action's two steps; the tilt stays in [0, 180°].
        w = float(np.clip(self.tilt + a[0] * self._turn, 0.0, np.pi) - self.tilt) / 2.0
        tap = max(float(a[1]), 0.0) * self._tap
        self.sim.set_controls(self.tool, [self._turn_row(w, -tap), self._turn_row(w, tap)])
        self.sim.step(2)
        self.tilt += 2.0 * w
        self.steps += 1
        done = self.steps >= self.max_steps
        info: Dict[str, Any] = {"params": self._params_info(), "target_mg": self.target}
        reward = 0.0
        if done:
            # Back upright at the turn's speed, then let the powder land and the balance settle.
            back = []
            tilt = self.tilt
            while tilt > 0.0:
                w = min(self._turn, tilt)
                back.append(self._turn_row(-w))
                tilt -= w
            rows = back + [self._turn_row(0.0)] * self.settle_steps
            if rows:
                self.sim.set_controls(self.tool, rows)
                self.sim.step(len(rows))
            self.tilt = 0.0
            delivered = self.sim.score()["transported"] * 1e3
            info.update({"delivered_mg": delivered, "error_mg": delivered - self.target})
            reward = -abs(delivered - self.target)
        return self._obs(), float(reward), done, False, info


gym.register(id="powderlab/SkillTransport-v0", entry_point="powderlab.envs:SkillEnv")
gym.register(id="powderlab/ToolControl-v0", entry_point="powderlab.envs:ToolControlEnv")
gym.register(id="powderlab/Weighing-v0", entry_point="powderlab.envs:WeighingEnv")
