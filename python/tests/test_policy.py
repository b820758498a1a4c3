"""The policy dataset on Ray: the same files as `powderlab policy dataset`, and a rerun that
finds every scene done."""

import subprocess

import ray

import powderlab
from powderlab.distributed import map_dataset

from conftest import TINY

RANDOMIZE = """    randomize: Some((
        source: "source_cup",
        fill_height: Some((0.015, 0.020)),
        friction_deg: Some((25.0, 35.0)),
        target_g: Some((1.0, 3.0)),
    )),
"""


def _scene(tmp_path):
    text = TINY.read_text().rstrip()
    assert text.endswith(")")
    path = tmp_path / "tiny_policy.ron"
    path.write_text(text[:-1] + RANDOMIZE + ")\n")
    return path


def test_ray_dataset_files_equal_the_command_s(tmp_path, cli):
    path = _scene(tmp_path)
    opts = ["--scenes", "2", "--budget", "2", "--augment", "1"]
    subprocess.run(
        [str(cli), "policy", "dataset", str(path), "--dir", str(tmp_path / "cli"), *opts],
        check=True, capture_output=True,
    )
    scene = powderlab.Scene.load(path)
    try:
        out = map_dataset(
            scene, tmp_path / "ray", scenes=2, budget=2, augment=1,
            num_cpus=2, include_dashboard=False,
        )
    finally:
        ray.shutdown()
    assert out.endswith("dataset.safetensors")
    for k in range(2):
        name = f"scene-{k}.json"
        assert (tmp_path / "ray" / name).read_bytes() == (tmp_path / "cli" / name).read_bytes()
    # The command on the Ray folder finds every scene done and simulates nothing.
    stamps = [(tmp_path / "ray" / f"scene-{k}.json").stat().st_mtime_ns for k in range(2)]
    r = subprocess.run(
        [str(cli), "policy", "dataset", str(path), "--dir", str(tmp_path / "ray"), *opts],
        check=True, capture_output=True, text=True,
    )
    assert "4 samples" in r.stdout
    assert stamps == [(tmp_path / "ray" / f"scene-{k}.json").stat().st_mtime_ns for k in range(2)]
