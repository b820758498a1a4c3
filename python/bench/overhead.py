"""The bindings' per-rollout overhead against the CLI, and map_rollouts' speed-up on a local
2-CPU Ray against one process. Writes docs/results/python.md.

    python python/bench/overhead.py --out docs/results/python.md

Needs the CLI (`cargo build --release`; found as in the tests: $POWDERLAB_BIN, then the release
binary in $CARGO_TARGET_DIR or target/) and the package with Ray (`pip install ./python[ray]`).
Every timing is the median of paired, interleaved runs on this machine, so that a slower
moment hits both sides.
"""

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "python" / "tests"))

import powderlab  # noqa: E402
from conftest import _binary  # noqa: E402


def machine() -> str:
    model = platform.processor() or "unknown CPU"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    mem = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**30
    return f"{model}, {os.cpu_count()} cores, {mem:.0f} GiB, Python {platform.python_version()}"


def timed(f):
    t = time.perf_counter()
    out = f()
    return time.perf_counter() - t, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "powder_transport.ron"))
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--rollouts", type=int, default=8, help="rollouts of the Ray comparison")
    ap.add_argument("--out", default=str(ROOT / "docs" / "results" / "python.md"))
    a = ap.parse_args()
    cli = _binary()
    scene_path = Path(a.scene)
    rel = scene_path.resolve().relative_to(ROOT) if scene_path.resolve().is_relative_to(ROOT) else scene_path
    scene = powderlab.Scene.load(scene_path)
    one_rollout = (
        "import powderlab as p; p.rollout(p.Scene.load(%r), threads=2)" % str(scene_path)
    )

    # 1. One forward rollout of the default scene, 2 threads: the CLI process, a Python process
    #    doing the same, and rollout() inside a running interpreter.
    cli_s, py_proc_s, py_call_s = [], [], []
    for _ in range(a.repeats):
        cli_s.append(timed(lambda: subprocess.run(
            [str(cli), "simulate", str(scene_path), "--threads", "2"],
            check=True, capture_output=True))[0])
        py_proc_s.append(timed(lambda: subprocess.run(
            [sys.executable, "-c", one_rollout], check=True, capture_output=True))[0])
        py_call_s.append(timed(lambda: powderlab.rollout(scene, threads=2))[0])
    import_s = statistics.median(
        timed(lambda: subprocess.run([sys.executable, "-c", "import powderlab"], check=True))[0]
        for _ in range(a.repeats)
    )
    grad_s = statistics.median(
        timed(lambda: powderlab.rollout(scene, grad=True, threads=2))[0] for _ in range(3)
    )

    # 2. The Ray comparison: the same rollouts one by one in this process (1 thread and 2
    #    threads per rollout) and as Ray tasks on a local 2-CPU Ray (1 thread each).
    import ray
    from powderlab.distributed import map_rollouts

    thetas = [[((7 * i + k) % 9) / 4.5 - 1.0 for k in range(5)] for i in range(a.rollouts)]
    seq1, r1 = timed(lambda: [powderlab.rollout(scene, theta=t, threads=1) for t in thetas])
    seq2, _ = timed(lambda: [powderlab.rollout(scene, theta=t, threads=2) for t in thetas])
    init_s, _ = timed(lambda: ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False))
    ray_s, rr = timed(lambda: map_rollouts(scene, thetas))
    ray.shutdown()
    same = all(x["loss"] == y["loss"] and (x["positions"] == y["positions"]).all() for x, y in zip(r1, rr))

    med = statistics.median
    lines = [
        "# Python bindings and Ray",
        "",
        f"Regenerate with `python python/bench/overhead.py` ({machine()}).",
        "",
        f"## One rollout from Python against the CLI (`{rel}`, 2 threads)",
        "",
        f"Median of {a.repeats} interleaved runs each. The CLI is `powderlab simulate` (which also "
        "computes the energy budget every step); the Python process loads the scene and calls "
        "`powderlab.rollout`; the call is `rollout()` inside a running interpreter (scene built, "
        "run, loss and dose scored, final state copied to numpy).",
        "",
        "| what | seconds | against the CLI |",
        "|---|---|---|",
        f"| `powderlab simulate` (a process) | {med(cli_s):.3f} | 1.00 |",
        f"| `python -c 'rollout(...)'` (a process) | {med(py_proc_s):.3f} | {med(py_proc_s) / med(cli_s):.2f} |",
        f"| `rollout()` in a running interpreter | {med(py_call_s):.3f} | {med(py_call_s) / med(cli_s):.2f} |",
        f"| `import powderlab` (a process) | {import_s:.3f} | |",
        f"| `rollout(grad=True)` in a running interpreter | {grad_s:.3f} | {grad_s / med(cli_s):.2f} |",
        "",
        f"Per-rollout overhead of the bindings: {1e3 * (med(py_call_s) - med(cli_s)):+.0f} ms "
        f"({100 * (med(py_call_s) / med(cli_s) - 1):+.1f} %) against the CLI process"
        + (" (below zero: the CLI's energy budget every step costs more than the bindings add)"
           if med(py_call_s) < med(cli_s) else "")
        + f"; a Python process pays the interpreter and `import powderlab` ({import_s:.2f} s) once.",
        "",
        f"## {a.rollouts} rollouts: one process against `map_rollouts` on a local 2-CPU Ray",
        "",
        "Θ on a fixed grid in [-1, 1]^5. Ray's tasks run one thread each; its start-up "
        f"(`ray.init`, {init_s:.1f} s) is paid once per session and not counted.",
        "",
        "| how | seconds | speed-up |",
        "|---|---|---|",
        f"| one by one, 1 thread | {seq1:.1f} | 1.00 |",
        f"| one by one, 2 threads | {seq2:.1f} | {seq1 / seq2:.2f} |",
        f"| `map_rollouts`, 2 Ray workers × 1 thread | {ray_s:.1f} | {seq1 / ray_s:.2f} |",
        "",
        f"The Ray results are bitwise those of the one-by-one run: {'yes' if same else 'NO'}.",
        "",
    ]
    out = Path(a.out)
    with tempfile.NamedTemporaryFile("w", dir=out.parent, delete=False, suffix=".partial") as f:
        f.write("\n".join(lines))
    os.replace(f.name, out)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
