#!/usr/bin/env python3
"""Measures the rest rule (`powderlab::sim::rest`) on weighing doses: each target dosed with
resting powder set aside and with every particle simulated (`weigh --no-rest`), alternated, on
the shipped `scenes/vial_weighing.ron` and 2 threads. Prints the table of docs/results/rest.md.

    python3 scripts/rest_lever.py [--targets 10,30] [--pairs 1]
"""
import argparse
import json
import os
import subprocess

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TARGET_DIR = os.environ.get("CARGO_TARGET_DIR", os.path.expanduser("~/.cache/powderlab-target"))
BIN = os.path.join(TARGET_DIR, "release", "powderlab")


def dose(target, rest):
    cmd = [BIN, "weigh", "scenes/vial_weighing.ron", "--target-mg", str(target),
           "--threads", "2", "--json"] + ([] if rest else ["--no-rest"])
    out = subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True).stdout
    return json.loads(out.strip().splitlines()[-1])


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--targets", default="10,30")
    ap.add_argument("--pairs", type=int, default=1)
    a = ap.parse_args()
    subprocess.run(["cargo", "build", "--release", "--quiet"], cwd=ROOT, check=True)
    print("| target | run | delivered | scoops | simulated | particle-substeps | wall | wall ratio |")
    print("|---|---|---|---|---|---|---|---|")
    for t in [float(x) for x in a.targets.split(",")]:
        for k in range(a.pairs):
            # Alternate which one runs first.
            order = [False, True] if k % 2 == 0 else [True, False]
            r = {rest: dose(t, rest) for rest in order}
            ratio = r[False]["wall_s"] / r[True]["wall_s"]
            for rest in [False, True]:
                d = r[rest]
                print(f"| {t:g} mg | {'rest' if rest else 'every particle'} | "
                      f"{d['delivered_mg']:.2f} mg | {d['scoops']} | {d['sim_s']:.2f} s | "
                      f"{d['particle_substeps'] / 1e9:.3f} G | {d['wall_s']:.1f} s | "
                      f"{ratio:.2f}× |", flush=True)


if __name__ == "__main__":
    main()
