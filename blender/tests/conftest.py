"""The Blender add-on's tests: bpy (from PyPI) in this venv, the add-on
installed from the zip blender/build-zip.sh builds, and a real farm on
loopback (a coordinator and one worker, with a token), started as
python/tests/conftest.py starts them.

Environment: SYLVA_BIN (the `sylva` binary, default target/release/sylva),
SYLVA_BLENDER_ZIP (the add-on's zip; default: built here into the test's
temporary folder).
"""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import sys
import tempfile
import threading
import time
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

sys.path.insert(0, str(HERE))


def sylva_bin() -> Path:
    return Path(os.environ.get("SYLVA_BIN") or REPO / "target" / "release" / "sylva")


@pytest.fixture(scope="session")
def sylva() -> Path:
    b = sylva_bin()
    if not os.access(b, os.X_OK):
        pytest.fail(f"no sylva binary at {b}: build it (cargo build --release) or set SYLVA_BIN")
    return b


def child_env(**extra: str) -> dict[str, str]:
    """The environment of a `sylva` process (python/tests/conftest.py's)."""
    env = dict(os.environ)
    for k in ("SYLVA_TOKEN", "SYLVA_STATE_DIR", "SYLVA_DATABASE_URL",
              "SYLVA_PREPARED_CACHE_DIR", "SYLVA_COORDINATOR"):
        env.pop(k, None)
    runtime = Path(os.environ.get("SYLVA_TEST_RUNTIME_DIR", "/tmp/sylva-runtime-0"))
    runtime.mkdir(mode=0o700, parents=True, exist_ok=True)
    env.update(XDG_RUNTIME_DIR=str(runtime), SYLVA_PREPARED_CACHE_MIB="0")
    env.update(extra)
    return env


class Proc:
    """A `sylva` process serving on loopback: its address and its log."""

    def __init__(self, binary: Path, args: list[str], log: Path, **env: str) -> None:
        self.log = log
        with open(log, "wb") as err:
            self.child = subprocess.Popen([str(binary), *args], env=child_env(**env),
                                          stdout=subprocess.PIPE, stderr=err,
                                          stdin=subprocess.DEVNULL)
        line: list[bytes] = []
        reader = threading.Thread(target=lambda: line.append(self.child.stdout.readline()))
        reader.start()
        reader.join(60)
        said = line[0].decode(errors="replace") if line else ""
        if " listening on " not in said:
            self.stop()
            raise RuntimeError(f"sylva {args} did not start: {said!r}\n{log.read_text()[-4000:]}")
        self.addr = said.strip().rsplit(" ", 1)[-1]
        threading.Thread(target=self.child.stdout.read, daemon=True).start()

    def stop(self) -> None:
        if self.child.poll() is None:
            self.child.send_signal(signal.SIGTERM)
            try:
                self.child.wait(5)
            except subprocess.TimeoutExpired:
                self.child.kill()
                self.child.wait()


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
    token = secrets.token_hex(16)
    coord = Proc(sylva, ["coordinator", "--listen", "127.0.0.1:0", "--token", token,
                         "--ephemeral", "--max-running", "1"], logs / "coordinator.log")
    try:
        worker = Proc(sylva, ["worker", "--listen", "127.0.0.1:0", "--coordinator", coord.addr],
                      logs / "worker.log", SYLVA_TOKEN=token)
    except BaseException:
        coord.stop()
        raise
    try:
        client = addon.deps.client_module()  # the vendored client
        with client.Client(coord.addr, token=token) as c:
            t = time.monotonic()
            while sum(w.alive for w in c.workers()) < 1:
                if time.monotonic() - t > 60:
                    raise RuntimeError("the worker did not register")
                time.sleep(0.05)
        yield {"addr": coord.addr, "token": token, "logs": logs}
    finally:
        worker.stop()
        coord.stop()
