#!/usr/bin/env python3
"""Runs powderlab and the Taichi reference on the same sand_box scene, back to back on the
same machine, and prints both throughputs and their ratio (one JSON object on the last line).

    pip install taichi==1.7.4
    cargo build --release
    python3 scripts/compare_taichi.py [--n-grid 48] [--threads 2] [--rounds 1]

Both report particle-substeps per second of the timed forward run, excluding start-up:
Taichi's JIT warm-up step and powderlab's scene build are outside the timed region.
"""
import argparse, json, os, subprocess, sys, pathlib

ROOT = pathlib.Path(__file__).resolve().parent.parent
REF = ROOT.parent / "shared" / "reference" / "taichi_mpm_bench.py"


def last_json(text):
    for line in reversed(text.strip().splitlines()):
        line = line.strip()
        if line.startswith("{"):
            return json.loads(line)
    raise RuntimeError("no JSON line in output:\n" + text[-2000:])


def cpu_model():
    """The CPU's model name and whether it has AVX-512. Taichi's speed has differed by about 2x
    between sittings, more than powderlab's, and this project's machines have been of more than
    one CPU kind (an Intel Sapphire Rapids class with AVX-512, an AMD EPYC with AVX2 only); whether
    the two are linked is not known, so every ratio names its CPU."""
    model, avx512 = "unknown", False
    try:
        for line in pathlib.Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name") and model == "unknown":
                model = line.split(":", 1)[1].strip()
            if line.startswith("flags"):
                avx512 = avx512 or " avx512f" in line
    except OSError:
        pass
    return model, avx512


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--n-grid", type=int, default=48)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1, help="alternate the two this many times")
    ap.add_argument("--powderlab", default=None, help="path of the powderlab binary")
    ap.add_argument("--backward", action="store_true",
                    help="compare forward+backward (Taichi's ti.ad.Tape, powderlab bench --backward)")
    ap.add_argument("--svd", choices=["F64", "F32"], default="F64",
                    help="powderlab's SVD precision (the scene's simulation.svd)")
    args = ap.parse_args()
    target = os.environ.get("CARGO_TARGET_DIR", str(ROOT / "target"))
    exe = args.powderlab or str(pathlib.Path(target) / "release" / "powderlab")
    scene = ROOT / "scenes" / "sand_box.ron"
    if args.n_grid != 48:
        src = scene.read_text()
        dx = repr(1.0 / args.n_grid)
        src = src.replace("cells: (48, 48, 48)", f"cells: ({args.n_grid}, {args.n_grid}, {args.n_grid})")
        src = src.replace("dx: 0.020833333333333332", f"dx: {dx}")
        scene = pathlib.Path(os.environ.get("TMPDIR", "/tmp")) / f"sand_box_n{args.n_grid}.ron"
        scene.write_text(src)
    if args.svd != "F64":
        src = scene.read_text().replace("empty_node_ratio: 1e-6,", f"empty_node_ratio: 1e-6, svd: {args.svd},")
        scene = pathlib.Path(os.environ.get("TMPDIR", "/tmp")) / f"sand_box_n{args.n_grid}_svd{args.svd}.ron"
        scene.write_text(src)
    rows = []
    for r in range(args.rounds):
        if args.backward:
            t = subprocess.run([sys.executable, str(REF), "--n-grid", str(args.n_grid), "--steps", "20",
                                "--threads", str(args.threads), "--arch", "cpu", "--backward", "--fd", "off"],
                               capture_output=True, text=True, check=True)
            tj = last_json(t.stdout)
            p = subprocess.run([exe, "bench", str(scene), "--threads", str(args.threads), "--json", "--backward"],
                               capture_output=True, text=True, check=True)
            pj = last_json(p.stdout)
            row = {"round": r,
                   "taichi_particle_substeps_per_s": tj["particle_substeps_per_second_forward_plus_backward"],
                   "powderlab_particle_substeps_per_s": pj["particle_substeps_per_s_forward_backward"],
                   "taichi_peak_rss_mb": tj["peak_rss_mb"], "powderlab_peak_rss_mb": pj["peak_rss_bytes"] / 2**20,
                   "taichi_grad_tool_velocity": tj["grad_tool_velocity"],
                   "powderlab_grad_tool_velocity": pj["grad_tool_velocity"][0]["dloss_dvelocity"],
                   "taichi_grad_v0_sum": tj["grad_v0"]["sum"], "powderlab_grad_v0_sum": pj["grad_v0_sum"],
                   "taichi_loss": tj["loss_tape_run"], "powderlab_loss": pj["loss"]}
            row["ratio"] = row["powderlab_particle_substeps_per_s"] / row["taichi_particle_substeps_per_s"]
            rows.append(row)
            print(f"round {r}: backward: taichi {row['taichi_particle_substeps_per_s']/1e6:.3f} M/s, "
                  f"powderlab {row['powderlab_particle_substeps_per_s']/1e6:.3f} M/s, ratio {row['ratio']:.2f}",
                  file=sys.stderr)
            continue
        t = subprocess.run([sys.executable, str(REF), "--n-grid", str(args.n_grid), "--steps", "20",
                            "--threads", str(args.threads), "--arch", "cpu"],
                           capture_output=True, text=True, check=True)
        tj = last_json(t.stdout)
        p = subprocess.run([exe, "bench", str(scene), "--threads", str(args.threads), "--json"],
                           capture_output=True, text=True, check=True)
        pj = last_json(p.stdout)
        row = {"round": r, "taichi_particle_substeps_per_s": tj["particle_substeps_per_second_forward"],
               "powderlab_particle_substeps_per_s": pj["particle_substeps_per_s"],
               "taichi_final_mean_position": tj["final_mean_position"],
               "powderlab_final_mean_position": pj["final_mean_position_m"],
               "particles": pj["particles"], "taichi_particles": tj["particles"]}
        row["ratio"] = row["powderlab_particle_substeps_per_s"] / row["taichi_particle_substeps_per_s"]
        rows.append(row)
        print(f"round {r}: taichi {row['taichi_particle_substeps_per_s']/1e6:.3f} M/s, "
              f"powderlab {row['powderlab_particle_substeps_per_s']/1e6:.3f} M/s, ratio {row['ratio']:.2f}",
              file=sys.stderr)
    ratios = sorted(r["ratio"] for r in rows)
    model, avx512 = cpu_model()
    print(f"cpu: {model}, AVX-512 {'yes' if avx512 else 'no'}", file=sys.stderr)
    print(json.dumps({"n_grid": args.n_grid, "threads": args.threads, "cpu": model,
                      "avx512": avx512, "rounds": rows,
                      "median_ratio": ratios[len(ratios) // 2]}))


if __name__ == "__main__":
    main()
