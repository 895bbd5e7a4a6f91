"""Helpers the tests share: the `sylva` binary, its processes on loopback
(stopped when the tests are done; `sylva_client.local`) and a small farm.

The binary is ``$SYLVA_BIN``, else ``target/release/sylva`` at the
repository's root. Processes get the environment the Rust integration
tests give theirs (tests/common/mod.rs): a private runtime folder, no
prepared-data disk cache, an ephemeral coordinator state, and no token
inherited from the caller.
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Iterator
from pathlib import Path

import pytest

from sylva_client.local import LocalFarm, SylvaProcess, child_env

# The names the tests use.
Farm = LocalFarm
Proc = SylvaProcess

REPO = Path(__file__).resolve().parents[2]
EXAMPLES = REPO / "examples"


def sylva_bin() -> Path:
    """The `sylva` binary the tests run."""
    return Path(os.environ.get("SYLVA_BIN") or REPO / "target" / "release" / "sylva")


@pytest.fixture(scope="session")
def sylva() -> Path:
    """The `sylva` binary; the tests that need it fail without it."""
    b = sylva_bin()
    if not os.access(b, os.X_OK):
        pytest.fail(f"no sylva binary at {b}: build it (cargo build --release) or set SYLVA_BIN")
    return b


def run_sylva(binary: Path, *args: str, **env: str) -> subprocess.CompletedProcess[str]:
    """Runs `sylva ARGS` to its end."""
    return subprocess.run(
        [str(binary), *args],
        check=False,
        env=child_env(**env),
        capture_output=True,
        text=True,
        timeout=120,
    )


def small_scene(folder: Path) -> Path:
    """The Rust tests' small scene (tests/common/mod.rs): two small trees,
    local lighting (no LB solve), so it renders fast."""
    folder.mkdir(parents=True, exist_ok=True)
    p = folder / "scene.json"
    p.write_text(
        """{
        "models": { "maple": { "tree": { "species": "red_maple", "triangles": 3000, "seed": 1 } } },
        "instances": [ { "model": "maple", "position": [0, 0, 0] }, { "model": "maple", "position": [8, 0, 4], "rotate_y_deg": 30 } ],
        "camera": { "position": [4, 8, -26], "look_at": [4, 7, 0], "fov_y_deg": 45 },
        "sun": { "elevation_deg": 50, "azimuth_deg": 120 },
        "ground": { "color": [0.1, 0.08, 0.05] },
        "lighting": "local",
        "lb": { "grid": 8, "preset": "leaf" }
    }"""
    )
    return p


@pytest.fixture(scope="session")
def farm(sylva: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[LocalFarm]:
    """A coordinator (one job at a time, so others queue) and a worker
    that registers with it, both with a fresh token."""
    logs = tmp_path_factory.mktemp("farm")
    with LocalFarm.start(sylva, 1, logs=logs, coordinator_args=["--max-running", "1"]) as f:
        yield f
