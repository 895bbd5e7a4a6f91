"""A farm on this machine: a coordinator and workers on loopback, started
from a `sylva` binary, for scripts and tests (what `sylva render` does
with its local workers, from Python).

    with LocalFarm.start("target/release/sylva", workers=2) as farm:
        with farm.client() as c:
            job = c.submit("examples/ferns.json", Frame(width=320, height=180))

Processes get a private runtime folder, no prepared-data disk cache, an
ephemeral coordinator state and no token inherited from the caller (as
the Rust integration tests give theirs, tests/common/mod.rs), and are
stopped with SIGTERM (so they remove their temporary folders).
"""

from __future__ import annotations

import os
import secrets
import signal
import subprocess
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from types import TracebackType

from .client import Client

__all__ = ["LocalFarm", "SylvaProcess", "child_env"]

#: What a caller's environment may set that a started process must not inherit.
_FOREIGN = (
    "SYLVA_TOKEN",
    "SYLVA_STATE_DIR",
    "SYLVA_DATABASE_URL",
    "SYLVA_PREPARED_CACHE_DIR",
    "SYLVA_COORDINATOR",
)


def child_env(**extra: str) -> dict[str, str]:
    """The environment of a `sylva` process started here."""
    env = dict(os.environ)
    for k in _FOREIGN:
        env.pop(k, None)
    runtime = Path(os.environ.get("SYLVA_TEST_RUNTIME_DIR", "/tmp/sylva-runtime-0"))
    runtime.mkdir(mode=0o700, parents=True, exist_ok=True)
    # A private runtime folder silences the Vulkan loader's warning; prepared
    # data kept on disk would carry one run's work into the next.
    env.update(XDG_RUNTIME_DIR=str(runtime), SYLVA_PREPARED_CACHE_MIB="0")
    env.update(extra)
    return env


class SylvaProcess:
    """A `sylva` process serving on loopback: its address, and its log."""

    def __init__(self, binary: str | os.PathLike[str], args: list[str], log: Path, **env: str) -> None:
        self.log = log
        self.args = args
        with open(log, "wb") as err:
            self.child = subprocess.Popen(
                [os.fspath(binary), *args],
                env=child_env(**env),
                stdout=subprocess.PIPE,
                stderr=err,
                stdin=subprocess.DEVNULL,
            )
        # The first line announces the address: "... listening on ADDR".
        line: list[bytes] = []
        out = self.child.stdout
        assert out is not None
        reader = threading.Thread(target=lambda: line.append(out.readline()))
        reader.start()
        reader.join(60)
        said = line[0].decode(errors="replace") if line else ""
        if " listening on " not in said:
            self.stop()
            raise RuntimeError(f"sylva {args} did not start: {said!r}\n{self.log_text()}")
        self.addr = said.strip().rsplit(" ", 1)[-1]
        # Keep reading stdout so the process never blocks on a full pipe.
        threading.Thread(target=out.read, daemon=True).start()

    def log_text(self) -> str:
        """The end of its log."""
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
class LocalFarm:
    """A coordinator and its workers on loopback, all with one token."""

    coordinator: SylvaProcess
    workers: list[SylvaProcess]
    token: str
    logs: Path
    _stopped: bool = field(default=False, repr=False)

    @classmethod
    def start(
        cls,
        binary: str | os.PathLike[str],
        workers: int = 1,
        *,
        token: str | None = None,
        logs: Path | None = None,
        coordinator_args: list[str] | None = None,
        within: float = 60.0,
    ) -> LocalFarm:
        """Starts the coordinator (ephemeral state, `coordinator_args`
        added), then `workers` workers that register with it; returns once
        they all have. `token`: a fresh random one by default."""
        token = token or secrets.token_hex(16)
        logs = logs or Path(tempfile.mkdtemp(prefix="sylva-farm-"))
        args = ["coordinator", "--listen", "127.0.0.1:0", "--token", token, "--ephemeral"]
        coord = SylvaProcess(binary, args + (coordinator_args or []), logs / "coordinator.log")
        farm = cls(coord, [], token, logs)
        try:
            for i in range(workers):
                # A worker takes the farm's token from SYLVA_TOKEN.
                w = ["worker", "--listen", "127.0.0.1:0", "--coordinator", coord.addr]
                farm.workers.append(SylvaProcess(binary, w, logs / f"worker-{i}.log", SYLVA_TOKEN=token))
            with farm.client() as c:
                t = time.monotonic()
                while sum(w.alive for w in c.workers()) < workers:
                    if time.monotonic() - t > within:
                        raise RuntimeError(f"the workers did not register within {within} s")
                    time.sleep(0.05)
        except BaseException:
            farm.stop()
            raise
        return farm

    @property
    def addr(self) -> str:
        """The coordinator's address."""
        return self.coordinator.addr

    def client(self) -> Client:
        """A client of the coordinator, with the farm's token."""
        return Client(self.addr, token=self.token)

    def stop(self) -> None:
        """Stops the workers, then the coordinator."""
        if not self._stopped:
            self._stopped = True
            for w in self.workers:
                w.stop()
            self.coordinator.stop()

    def __enter__(self) -> LocalFarm:
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        value: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.stop()
