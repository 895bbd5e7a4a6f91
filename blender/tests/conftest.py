"""The Blender add-on's tests: bpy (from PyPI) in this venv, the add-on
installed from the zip blender/build-zip.sh builds, and a real farm on
loopback (a coordinator and one worker, with a token), started by the
client's `sylva_client.local`.

Environment: SYLVA_BIN (the `sylva` binary, default target/release/sylva),
SYLVA_BLENDER_ZIP (the add-on's zip; default: built here into the test's
temporary folder).
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
HERE = Path(__file__).resolve().parent

# Blender's user folders go to a temporary one, before bpy is imported, so
# that installing the add-on leaves the user's own Blender alone.
_USER = Path(tempfile.mkdtemp(prefix="sylva-bpy-user-"))
os.environ["BLENDER_USER_SCRIPTS"] = str(_USER / "scripts")
os.environ["BLENDER_USER_CONFIG"] = str(_USER / "config")
os.environ["BLENDER_USER_RESOURCES"] = str(_USER)
os.environ["BLENDER_USER_EXTENSIONS"] = str(_USER / "extensions")
os.environ.setdefault("SYLVA_BLENDER_DEPS", str(_USER / "deps"))

import bpy  # noqa: E402
from sylva_client.local import LocalFarm, child_env  # noqa: E402, F401 (child_env: the tests')

sys.path.insert(0, str(HERE))


def sylva_bin() -> Path:
    return Path(os.environ.get("SYLVA_BIN") or REPO / "target" / "release" / "sylva")


@pytest.fixture(scope="session")
def sylva() -> Path:
    b = sylva_bin()
    if not os.access(b, os.X_OK):
        pytest.fail(f"no sylva binary at {b}: build it (cargo build --release) or set SYLVA_BIN")
    return b


@pytest.fixture(scope="session")
def addon_zip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    z = os.environ.get("SYLVA_BLENDER_ZIP")
    if z:
        return Path(z)
    out = tmp_path_factory.mktemp("zip") / "sylva_blender.zip"
    subprocess.run([str(REPO / "blender" / "build-zip.sh"), str(out)], check=True)
    return out


@pytest.fixture(scope="session")
def addon(addon_zip: Path):  # noqa: ANN201 (the add-on's module)
    """The add-on, installed from its zip and enabled as a user would."""
    assert "FINISHED" in bpy.ops.preferences.addon_install(filepath=str(addon_zip), overwrite=True)
    assert "FINISHED" in bpy.ops.preferences.addon_enable(module="sylva_blender")
    import sylva_blender

    assert Path(sylva_blender.__file__).is_relative_to(_USER), sylva_blender.__file__
    yield sylva_blender
    bpy.ops.preferences.addon_disable(module="sylva_blender")


@pytest.fixture(scope="session")
def farm(sylva: Path, addon, tmp_path_factory: pytest.TempPathFactory) -> Iterator[dict]:
    """A coordinator and one worker on loopback, both with a fresh token."""
    logs = tmp_path_factory.mktemp("farm")
    with LocalFarm.start(sylva, 1, logs=logs, coordinator_args=["--max-running", "1"]) as f:
        yield {"addr": f.addr, "token": f.token, "logs": logs}
