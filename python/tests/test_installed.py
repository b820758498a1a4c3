"""The package as a user installs it: the wheel, in a fresh virtual environment, used from a
folder outside the checkout. The shipped scenes must come with it (``powderlab.scenes()``,
``Scene.shipped``), and every registered environment must make with its defaults.

This builds the wheel (maturin reuses the release build in $CARGO_TARGET_DIR) and installs it,
with gymnasium, into a new venv from the package index, so it needs the index to be reachable.
"""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]

# What runs inside the fresh venv, from an empty folder: no `scenes/` beside it, and the
# checkout's `python/` is not on the path (the venv has no access to the system packages).
CHECK = textwrap.dedent(
    """
    import os, sys
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env
    import powderlab, powderlab.envs

    assert not os.path.exists("scenes"), os.getcwd()
    assert "site-packages" in powderlab.__file__, powderlab.__file__
    ids = sorted(i for i in gym.registry if i.startswith("powderlab/"))
    assert ids == ["powderlab/SkillTransport-v0", "powderlab/ToolControl-v0",
                   "powderlab/Weighing-v0"], ids
    for env_id in ids[:2]:
        env = gym.make(env_id)  # the defaults: the shipped powder_transport
        check_env(env.unwrapped, skip_render_check=True)
        env.close()
    # The weighing default is the shipped 1 mm vial, minutes an episode: built, not stepped
    # (tests/test_envs.py runs the checker on it coarsened).
    env = gym.make(ids[2])
    assert sorted(env.observation_space.spaces) == ["params", "reading_mg", "target_mg", "tool"]
    env.close()
    names = powderlab.scenes()
    assert "powder_transport" in names and "free_fall" in names, names
    r = powderlab.rollout(powderlab.Scene.shipped("free_fall"), steps=3, threads=1)
    assert r["steps"] == 3, r
    try:
        powderlab.Scene.shipped("no_such_scene")
    except powderlab.SceneError as e:
        assert "powder_transport" in str(e) and "\\n" not in str(e), str(e)
    else:
        raise AssertionError("an unknown shipped name was accepted")
    print("installed package OK:", len(names), "shipped scenes,", ", ".join(ids))
    """
)


def run(cmd, **kw):
    p = subprocess.run(cmd, capture_output=True, text=True, **kw)
    assert p.returncode == 0, f"{' '.join(map(str, cmd))} failed:\n{p.stdout}\n{p.stderr}"
    return p.stdout


def test_the_installed_wheel_works_from_any_folder(tmp_path):
    wheels = tmp_path / "wheels"
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", wheels, ROOT / "python"])
    (wheel,) = wheels.glob("powderlab-*.whl")
    venv = tmp_path / "venv"
    run([sys.executable, "-m", "venv", venv])
    py = venv / ("Scripts" if os.name == "nt" else "bin") / "python"
    run([py, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", f"{wheel}[gym]"])
    work = tmp_path / "elsewhere"
    work.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    out = run([py, "-c", CHECK], cwd=work, env=env)
    assert "installed package OK" in out, out
