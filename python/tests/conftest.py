"""Helpers the tests share: the `sylva` binary, its processes on loopback
(stopped when the tests are done) and a small farm.

The binary is ``$SYLVA_BIN``, else ``target/release/sylva`` at the
repository's root. Processes get the environment the Rust integration
tests give theirs (tests/common/mod.rs): a private runtime folder, no
prepared-data disk cache, an ephemeral coordinator state, and no token
inherited from the caller.
"""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from sylva_client import Client

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


def child_env(**extra: str) -> dict[str, str]:
    """The environment of a `sylva` process the tests start."""
    env = dict(os.environ)
    for k in (
        "SYLVA_TOKEN",
        "SYLVA_STATE_DIR",
        "SYLVA_DATABASE_URL",
        "SYLVA_PREPARED_CACHE_DIR",
        "SYLVA_COORDINATOR",
    ):
        env.pop(k, None)
    runtime = Path(os.environ.get("SYLVA_TEST_RUNTIME_DIR", "/tmp/sylva-runtime-0"))
    runtime.mkdir(mode=0o700, parents=True, exist_ok=True)
    # A private runtime folder silences the Vulkan loader's warning; prepared
    # data kept on disk would carry one test's work into the next.
    env.update(XDG_RUNTIME_DIR=str(runtime), SYLVA_PREPARED_CACHE_MIB="0")
    env.update(extra)
    return env


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


class Proc:
    """A `sylva` process serving on loopback: its address, and its log."""

    def __init__(self, binary: Path, args: list[str], log: Path, **env: str) -> None:
        self.log = log
        self.args = args
        with open(log, "wb") as err:
            self.child = subprocess.Popen(
                [str(binary), *args],
                env=child_env(**env),
                stdout=subprocess.PIPE,
                stderr=err,
                stdin=subprocess.DEVNULL,
            )
        # The first line announces the address: "... listening on ADDR".
        line: list[bytes] = []
        reader = threading.Thread(target=lambda: line.append(self.child.stdout.readline()))
        reader.start()
        reader.join(60)
        said = line[0].decode(errors="replace") if line else ""
        if " listening on " not in said:
            self.stop()
            raise RuntimeError(f"sylva {args} did not start: {said!r}\n{self.log_text()}")
        self.addr = said.strip().rsplit(" ", 1)[-1]
        # Keep reading stdout so the process never blocks on a full pipe.
        threading.Thread(target=self.child.stdout.read, daemon=True).start()

    def log_text(self) -> str:
        try:
            return self.log.read_text(errors="replace")[-4000:]
        except OSError:
            return ""

    def stop(self) -> None:
        """SIGTERM (so it removes its temporary folders), then kill."""
        if self.child.poll() is None:
            self.child.send_signal(signal.SIGTERM)
            try:
                self.child.wait(5)
            except subprocess.TimeoutExpired:
                self.child.kill()
                self.child.wait()


@dataclass
class Farm:
    """A coordinator with one worker, both requiring `token`."""

    coordinator: Proc
    worker: Proc
    token: str

    @property
    def addr(self) -> str:
        return self.coordinator.addr

    def client(self) -> Client:
        return Client(self.addr, token=self.token)


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


def wait_for_workers(client: Client, n: int, within: float = 60.0) -> None:
    t = time.monotonic()
    while sum(w.alive for w in client.workers()) < n:
        if time.monotonic() - t > within:
            raise RuntimeError("the workers did not register")
        time.sleep(0.05)


@pytest.fixture(scope="session")
def farm(sylva: Path, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Farm]:
    """A coordinator (one job at a time, so others queue) and a worker
    that registers with it, both with a fresh token."""
    logs = tmp_path_factory.mktemp("farm")
    token = secrets.token_hex(16)
    coord = Proc(
        sylva,
        [
            "coordinator",
            "--listen",
            "127.0.0.1:0",
            "--token",
            token,
            "--ephemeral",
            "--max-running",
            "1",
        ],
        logs / "coordinator.log",
    )
    try:
        # The worker takes the farm's token from SYLVA_TOKEN, as in tests/service.rs.
        worker = Proc(
            sylva,
            ["worker", "--listen", "127.0.0.1:0", "--coordinator", coord.addr],
            logs / "worker.log",
            SYLVA_TOKEN=token,
        )
    except BaseException:
        coord.stop()
        raise
    f = Farm(coord, worker, token)
    try:
        with f.client() as c:
            wait_for_workers(c, 1)
        yield f
    finally:
        worker.stop()
        coord.stop()
