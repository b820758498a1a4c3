#!/usr/bin/env python3
"""Measures every figure of docs/results/performance.md in one run on this machine and prints
the page's tables in Markdown (raw JSON under --out).

    pip install taichi==1.7.4
    python3 scripts/performance.py [--out /tmp/powderlab-performance] [--pairs 5]

What it runs, in this order, so that each comparison is made back to back on the same machine:
1. builds this tree, and the commits before each speed lever (git worktrees, same target
   directory), to measure each lever against the build without it;
2. scripts/compare_taichi.py, forward and forward + backward (Taichi 1.7.4, CPU backend);
3. 1 -> 2 threads on sand_box, alternated;
4. backward / forward on the default scene and on sand_box;
5. each lever's ratio, alternated with the build (or the switch) without it;
6. the 1 mm vial-scale scene's rollout;
7. `powderlab study growth` (the growth table and figure, written to docs/results).
"""
import argparse, json, os, pathlib, subprocess, sys, time

ROOT = pathlib.Path(__file__).resolve().parent.parent
TARGET = pathlib.Path(os.environ.get("CARGO_TARGET_DIR", str(ROOT / "target")))

# Each lever: (name, the commit without it, the commit with it, what to compare).
LEVERS = [
    ("contracted transfers", "8a93fce", "ce5e740", "forward"),
    ("grid records packed to the active spans", "3ffff68", "2e24448", "memory"),
    ("records keep the principal stress, not the P2G affine term", "7bb2c24", "9e224e2", "memory"),
    ("4-wide grid nodes, transfer loops compiled for AVX2", "68347f7", "e34eb12", "forward"),
    ("4-wide grid nodes, transfer loops compiled for AVX2", "68347f7", "e34eb12", "backward"),
    ("small-angle Jacobi rotations in the SVD", "e34eb12", "683a78f", "forward"),
    ("SVD lanes in AVX registers", "89c60e3", "190be08", "forward"),
    ("SVD lanes in AVX registers", "89c60e3", "190be08", "backward"),
    ("return mapping in AVX registers, with fdlibm's ln and exp", "f087036", "5ea09d7", "forward"),
    ("return mapping in AVX registers, with fdlibm's ln and exp", "f087036", "5ea09d7", "backward"),
    ("G2P's gather four particles to an AVX register", "d06238b", "533ae00", "forward"),
    ("SVD groups handed to the lane kernel in place", "ba0e397", "d346914", "forward"),
]
BEFORE = "5b8b95d"  # the build before this page's levers


def sh(cmd, **kw):
    return subprocess.run(cmd, check=True, capture_output=True, text=True, **kw)


def last_json(text):
    for line in reversed(text.strip().splitlines()):
        if line.strip().startswith("{"):
            return json.loads(line)
    raise RuntimeError(text[-2000:])


def build(commit, out):
    """The powderlab binary of `commit` (None: this tree), copied to `out` (a commit's binary is
    kept there between runs). The trees share one target directory, and cargo tells a crate's
    freshness by its sources' times relative to the package root, whichever tree they are in:
    the crate's roots are touched first, or the tree built last would lend its library and
    binary to the next."""
    if commit is not None and out.exists():
        return out
    tree = ROOT
    if commit is not None:
        tree = pathlib.Path("/tmp") / f"powderlab-wt-{commit}"
        if not tree.exists():
            sh(["git", "worktree", "add", "--detach", str(tree), commit], cwd=ROOT)
    (tree / "src" / "lib.rs").touch()
    (tree / "src" / "main.rs").touch()
    sh(["cargo", "build", "--release", "--bin", "powderlab"], cwd=tree,
       env={**os.environ, "CARGO_TARGET_DIR": str(TARGET)})
    sh(["cp", str(TARGET / "release" / "powderlab"), str(out)])
    return out


def bench(exe, scene, *args):
    p = sh([str(exe), "bench", str(ROOT / "scenes" / scene), "--json", *args])
    return last_json(p.stdout)


def f32_scene(name, out):
    """The shipped scene `name` with `simulation.svd: F32`, written under `out`."""
    src = (ROOT / "scenes" / name).read_text()
    head, sep, rest = src.partition("simulation: (")
    assert sep, f"{name} has no simulation section"
    path = out / name.replace(".ron", "_svd_f32.ron")
    path.write_text(head + sep + "svd: F32, " + rest)
    return path


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--out", default="/tmp/powderlab-performance")
    ap.add_argument("--pairs", type=int, default=5)
    a = ap.parse_args()
    out = pathlib.Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    res = {}
    t0 = time.time()
    print("building", file=sys.stderr)
    commits = {BEFORE, *[l[1] for l in LEVERS], *[l[2] for l in LEVERS]}
    exe = {c: build(c, out / f"powderlab-{c}") for c in commits}
    # This tree last: the trees share the target directory, so the binary left in it after the
    # run is this tree's, not a lever commit's.
    exe["now"] = build(None, out / "powderlab-now")

    print("taichi", file=sys.stderr)
    env = {**os.environ, "CARGO_TARGET_DIR": str(TARGET)}
    for mode, extra in [("forward", []), ("backward", ["--backward"]),
                        ("forward_svd_f32", ["--svd", "F32"]),
                        ("backward_svd_f32", ["--backward", "--svd", "F32"])]:
        p = sh([sys.executable, str(ROOT / "scripts" / "compare_taichi.py"), "--rounds", "2",
                "--powderlab", str(exe["now"]), *extra], env=env)
        res[f"taichi_{mode}"] = last_json(p.stdout)

    print("scaling", file=sys.stderr)
    pairs = []
    for _ in range(a.pairs):
        one = bench(exe["now"], "sand_box.ron", "--threads", "1")["wall_s"]
        two = bench(exe["now"], "sand_box.ron", "--threads", "2")["wall_s"]
        # The machine's own ceiling, measured beside: two one-thread runs side by side take as
        # long as one alone when the VM gives two whole cores, longer when its vCPUs share one.
        cmd = [str(exe["now"]), "bench", str(ROOT / "scenes" / "sand_box.ron"), "--json",
               "--threads", "1"]
        procs = [subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True) for _ in range(2)]
        side = [last_json(p.communicate()[0])["wall_s"] for p in procs]
        pairs.append((one, two, side))
    res["scaling"] = pairs

    print("backward/forward", file=sys.stderr)
    bf = {}
    for scene in ["powder_transport.ron", "sand_box.ron"]:
        rows = []
        for _ in range(3):
            j = bench(exe["now"], scene, "--backward", "--threads", "2")
            fwd = j["timing_s"]["forward (taped)"]
            rows.append({"ratio": (j["wall_s"] - fwd) / fwd, "peak_mb": j["peak_rss_bytes"] / 1e6,
                         "wall_s": j["wall_s"]})
        bf[scene] = rows
    res["backward_over_forward"] = bf

    print("levers", file=sys.stderr)
    lev = {}
    # The active-block grid against its dense sweeps, in one binary.
    rows = []
    for _ in range(a.pairs):
        on = bench(exe["now"], "sand_box.ron", "--threads", "2")
        off = bench(exe["now"], "sand_box.ron", "--threads", "2", "--dense-grid")
        rows.append({"with": on["particle_substeps_per_s"], "without": off["particle_substeps_per_s"],
                     "same_bits": on["state_fingerprint"] == off["state_fingerprint"]})
    lev["active-block grid (sand_box)"] = rows
    # The f32 SVD against the f64 one, in one binary: the same scene with `svd: F32`.
    rows = []
    for _ in range(a.pairs):
        on = bench(exe["now"], str(f32_scene("sand_box.ron", out)), "--threads", "2")
        off = bench(exe["now"], "sand_box.ron", "--threads", "2")
        rows.append({"with": on["particle_substeps_per_s"], "without": off["particle_substeps_per_s"],
                     "mean_x_with": on["final_mean_position_m"],
                     "mean_x_without": off["final_mean_position_m"]})
    lev["f32 SVD (simulation.svd: F32, sand_box)"] = rows
    rows = []
    for _ in range(3):
        on = bench(exe["now"], str(f32_scene("sand_box.ron", out)), "--threads", "2", "--backward")
        off = bench(exe["now"], "sand_box.ron", "--threads", "2", "--backward")
        rows.append({"with_peak_mb": on["peak_rss_bytes"] / 1e6, "without_peak_mb": off["peak_rss_bytes"] / 1e6,
                     "with_rate": on["particle_substeps_per_s_forward_backward"],
                     "without_rate": off["particle_substeps_per_s_forward_backward"],
                     "same_gradient": on["grad_v0_sum"] == off["grad_v0_sum"]
                     and on["grad_tool_velocity"] == off["grad_tool_velocity"],
                     "grad_with": on["grad_tool_velocity"], "grad_without": off["grad_tool_velocity"]})
    lev["f32 SVD (simulation.svd: F32, sand_box) (forward + backward)"] = rows
    for name, without, with_, kind in LEVERS:
        rows = []
        w_exe = exe[with_]
        for _ in range({"forward": a.pairs, "backward": 3}.get(kind, 1)):
            if kind == "forward":
                on = bench(w_exe, "sand_box.ron", "--threads", "2")
                off = bench(exe[without], "sand_box.ron", "--threads", "2")
                rows.append({"with": on["particle_substeps_per_s"],
                             "without": off["particle_substeps_per_s"],
                             "mean_x_with": on["final_mean_position_m"],
                             "mean_x_without": off["final_mean_position_m"]})
            else:
                on = bench(w_exe, "sand_box.ron", "--threads", "2", "--backward")
                off = bench(exe[without], "sand_box.ron", "--threads", "2", "--backward")
                rows.append({"with_peak_mb": on["peak_rss_bytes"] / 1e6,
                             "without_peak_mb": off["peak_rss_bytes"] / 1e6,
                             "with_rate": on["particle_substeps_per_s_forward_backward"],
                             "without_rate": off["particle_substeps_per_s_forward_backward"],
                             "same_gradient": on["grad_v0_sum"] == off["grad_v0_sum"]
                             and on["grad_tool_velocity"] == off["grad_tool_velocity"],
                             "grad_with": on["grad_tool_velocity"],
                             "grad_without": off["grad_tool_velocity"]})
        lev[name + (" (forward + backward)" if kind == "backward" else "")] = rows
    # All of this page's levers together, against the build before them.
    rows = []
    for _ in range(a.pairs):
        on = bench(exe["now"], "sand_box.ron", "--threads", "2")
        off = bench(exe[BEFORE], "sand_box.ron", "--threads", "2")
        rows.append({"with": on["particle_substeps_per_s"], "without": off["particle_substeps_per_s"]})
    lev["all together (forward)"] = rows
    on = bench(exe["now"], "sand_box.ron", "--threads", "2", "--backward")
    off = bench(exe[BEFORE], "sand_box.ron", "--threads", "2", "--backward")
    lev["all together (backward memory)"] = [{"with_peak_mb": on["peak_rss_bytes"] / 1e6,
                                              "without_peak_mb": off["peak_rss_bytes"] / 1e6}]
    res["levers"] = lev

    print("vial", file=sys.stderr)
    res["vial"] = bench(exe["now"], "vial_scale.ron", "--threads", "2")
    res["vial_svd_f32"] = bench(exe["now"], str(f32_scene("vial_scale.ron", out)), "--threads", "2")

    print("growth", file=sys.stderr)
    p = sh([str(exe["now"]), "study", "growth", "--json", "--out", str(ROOT / "docs" / "results")],
           cwd=ROOT)
    res["growth"] = last_json(p.stdout)
    res["wall_s"] = time.time() - t0
    (out / "performance.json").write_text(json.dumps(res, indent=1))
    report(res)


def report(res):
    f = res["taichi_forward"]
    b = res["taichi_backward"]
    print(f"cpu: {f['cpu']}, AVX-512 {'yes' if f['avx512'] else 'no'}")
    print("\n| | Taichi 1.7.4 CPU (f32) | powderlab (f64) | ratio (goal 5×) |\n|---|---|---|---|")
    for name, d, key in [("forward", f, None), ("forward + backward", b, None),
                         ("forward, f32 SVD", res["taichi_forward_svd_f32"], None),
                         ("forward + backward, f32 SVD", res["taichi_backward_svd_f32"], None)]:
        for r in d["rounds"]:
            print(f"| {name}, round {r['round'] + 1} | {r['taichi_particle_substeps_per_s'] / 1e6:.3f} M/s "
                  f"| {r['powderlab_particle_substeps_per_s'] / 1e6:.3f} M/s | **{r['ratio']:.2f}×** |")
    r = b["rounds"][-1]
    print(f"| peak RSS, forward + backward | {r['taichi_peak_rss_mb']:,.0f} MB | {r['powderlab_peak_rss_mb']:,.0f} MB | |")
    print("\nscaling 1 -> 2 threads: " + ", ".join(
        f"{o:.3f} / {t:.3f} s ({o / t:.2f}×; two one-thread runs side by side {max(c) / o:.3f}× one alone)"
        for o, t, c in res["scaling"]))
    print("\n| scene | backward/forward | peak RSS |\n|---|---|---|")
    for s, rows in res["backward_over_forward"].items():
        print(f"| `{s}` | " + ", ".join(f"{x['ratio']:.2f}" for x in rows) + " | "
              + ", ".join(f"{x['peak_mb']:,.0f} MB" for x in rows) + " |")
    print("\n| lever | with / without |\n|---|---|")
    for name, rows in res["levers"].items():
        if "with" in rows[0]:
            rs = [x["with"] / x["without"] for x in rows]
            extra = ""
            if "same_bits" in rows[0]:
                extra = "; same bits" if all(x["same_bits"] for x in rows) else "; BITS DIFFER"
            print(f"| {name} | " + ", ".join(f"{x:.3f}" for x in rs) + f" (median {sorted(rs)[len(rs) // 2]:.3f}){extra} |")
        else:
            for x in rows:
                print(f"| {name} | peak RSS {x['with_peak_mb']:,.0f} MB against {x['without_peak_mb']:,.0f} MB"
                      + (f"; {x['with_rate'] / x['without_rate']:.3f}× the throughput; same gradient: {x['same_gradient']}"
                         if "with_rate" in x else "") + " |")
    for key in ["vial", "vial_svd_f32"]:
        v = res[key]
        ps = v["particles"] * v["substeps_total"]
        print(f"\n{key}: {v['particles']} particles, {v['substeps_total']} substeps ({v['steps']} steps), "
              f"{ps / 1e9:.3f} G particle-substeps in {v['wall_s']:.1f} s ({v['particle_substeps_per_s'] / 1e6:.2f} M/s); "
              f"0.23 G would take {0.23e9 / v['particle_substeps_per_s']:.1f} s")
    for name, rows in res["levers"].items():
        for x in rows:
            if "mean_x_with" in x and x["mean_x_with"] != x["mean_x_without"]:
                print(f"{name}: final mean position {x['mean_x_with']} against {x['mean_x_without']}")
                break
            if "grad_with" in x:
                print(f"{name}: tool-velocity gradient {x['grad_with']} against {x['grad_without']}")
                break
    g = res["growth"]
    print(f"\ngrowth: particle spread {g['particle_series_max_over_min_throughput']:.3f}, grid largest/smallest "
          f"{g['grid_series_largest_over_smallest']:.2f} (dense {g['grid_dense_series_largest_over_smallest']:.2f})")
    for x in g["active_grid_gain"]:
        print(f"  {x['cells']}: dense/active {x['dense_over_active']:.2f}, same bits {x['same_bits']}")
    for r in g["results"]:
        c = r["config"]
        print(f"| {c['series']} | {c['cells']} | {r['particles']:,} | {r['nodes']:,} | {r['seconds_per_substep'] * 1e3:.2f} "
              f"| {r['ns_per_particle_substep']:.1f} | {r['peak_rss_bytes'] / 1e6:.1f} MB |")
    print(f"\n(all measured in {res['wall_s']:.0f} s)")


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--report":
        report(json.loads(pathlib.Path(sys.argv[2]).read_text()))
    else:
        main()
