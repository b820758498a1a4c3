"""Shared fixtures: the repository's scenes and the powderlab command-line binary that the
bindings are compared against."""

import os
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
TINY = ROOT / "tests" / "scenes" / "tiny_transport.ron"


def _binary() -> Path:
    """The CLI built by `cargo build --release` (or `cargo test --release`): $POWDERLAB_BIN,
    else the release binary in $CARGO_TARGET_DIR or target/, else `powderlab` on the PATH."""
    if os.environ.get("POWDERLAB_BIN"):
        return Path(os.environ["POWDERLAB_BIN"])
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    for p in (target / "release" / "powderlab", ROOT / "target" / "release" / "powderlab"):
        if p.exists():
            return p
    found = shutil.which("powderlab")
    if found:
        return Path(found)
    raise RuntimeError(
        "no powderlab binary: run `cargo build --release` first, or set POWDERLAB_BIN"
    )


@pytest.fixture(scope="session")
def cli() -> Path:
    return _binary()


@pytest.fixture(scope="session")
def tiny():
    import powderlab

    return powderlab.Scene.load(TINY)
