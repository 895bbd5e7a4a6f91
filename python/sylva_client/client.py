"""A client of a Sylva coordinator: submit jobs, follow them, fetch their
images, list and cancel them — what `sylva submit`, `jobs`, `cancel` and
`fetch` do, as typed Python calls over the same gRPC API
(proto/sylva/v1/coordinator.proto).
"""

from __future__ import annotations

import json
import os
import socket
import threading
import unicodedata
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any

import grpc

from . import bundle as _bundle
from ._pb.sylva.v1 import coordinator_pb2 as _cpb
from ._pb.sylva.v1 import coordinator_pb2_grpc as _cgrpc
from .errors import JobFailedError, SylvaError
from .frame import SCHEDULES, Frame, View, _name

__all__ = ["Client", "JobEvent", "JobState", "JobSummary", "WorkerInfo", "load_token"]

#: Largest message either way, as the Rust client allows (a frame's EXR
#: can be large).
MAX_MESSAGE = 1 << 30
#: Bytes of the bundle per SubmitChunk, as `sylva submit` sends them.
CHUNK = 1 << 20
#: Longest job name and submitter the coordinator accepts, bytes.
MAX_NAME = 256
MAX_SUBMITTER = 64


class JobState(str, Enum):
    """Where a job is in its life: queued → running → done, failed or
    cancelled (the last three final). `UNKNOWN`: a state this client does
    not know (from a newer server)."""

    QUEUED = "queued"
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"
    UNKNOWN = "unknown"

    @property
    def ended(self) -> bool:
        """Whether the state is final."""
        return self in (JobState.DONE, JobState.FAILED, JobState.CANCELLED)

    @classmethod
    def from_wire(cls, v: int) -> JobState:
        """The state a wire number names."""
        return _STATES.get(v, cls.UNKNOWN)

    def __str__(self) -> str:
        return self.value


_STATES: dict[int, JobState] = {
    _cpb.JOB_STATE_QUEUED: JobState.QUEUED,
    _cpb.JOB_STATE_RUNNING: JobState.RUNNING,
    _cpb.JOB_STATE_DONE: JobState.DONE,
    _cpb.JOB_STATE_FAILED: JobState.FAILED,
    _cpb.JOB_STATE_CANCELLED: JobState.CANCELLED,
}


@dataclass(frozen=True)
class JobEvent:
    """One event of a job's progress, as `watch` yields them."""

    #: The job's id.
    id: str
    state: JobState
    strips_done: int
    strips_total: int
    #: The frame (of a sequence) of the strip just done; 0 for one frame.
    frame: int
    #: What the job is doing now, in words; empty: unchanged.
    stage: str
    #: Why a job failed, or a retry notice.
    message: str
    #: With done: the frame's stats (a sequence's: per frame), else None.
    stats: dict[str, Any] | None
    #: The worker of the strip just done, and its render time.
    worker: str
    strip_ms: float

    @property
    def ended(self) -> bool:
        """Whether this is the job's last event."""
        return self.state.ended

    @classmethod
    def from_proto(cls, e: _cpb.JobEvent) -> JobEvent:
        """The event a wire `JobEvent` holds."""
        stats: dict[str, Any] | None = None
        if e.stats_json:
            try:
                parsed = json.loads(e.stats_json)
                stats = parsed if isinstance(parsed, dict) else {"value": parsed}
            except ValueError:
                stats = None  # as the CLI: unreadable stats are none
        return cls(
            id=e.id,
            state=JobState.from_wire(e.state),
            strips_done=e.strips_done,
            strips_total=e.strips_total,
            frame=e.frame,
            stage=e.stage,
            message=e.message,
            stats=stats,
            worker=e.worker,
            strip_ms=e.strip_ms,
        )


@dataclass(frozen=True)
class JobSummary:
    """A job as the coordinator lists it (`sylva jobs --json`'s fields)."""

    id: str
    name: str
    state: JobState
    priority: int
    strips_done: int
    strips_total: int
    #: Frames in the job (1 unless a sequence), and frames finished.
    frames: int
    frames_done: int
    #: Strips sent again after a worker failed them.
    retries: int
    #: Who submitted it, and from where (``name@address``).
    submitter: str
    #: Milliseconds since the Unix epoch; None where not yet.
    submitted_unix_ms: int
    started_unix_ms: int | None
    finished_unix_ms: int | None
    #: Why it failed, if it did.
    error: str | None
    #: What the farm is doing for it now ("" once it ended), and the
    #: seconds left, estimated from the strips returned since the first
    #: (None before there is an estimate), as `sylva jobs` shows them.
    stage: str = ""
    eta_s: float | None = None

    @classmethod
    def from_proto(cls, j: _cpb.JobSummary) -> JobSummary:
        """The summary a wire `JobSummary` holds."""
        return cls(
            id=j.id,
            name=j.name,
            state=JobState.from_wire(j.state),
            priority=j.priority,
            strips_done=j.strips_done,
            strips_total=j.strips_total,
            frames=max(j.frames, 1),
            frames_done=j.frames_done,
            retries=j.retries,
            submitter=j.submitter,
            submitted_unix_ms=j.submitted_unix_ms,
            started_unix_ms=j.started_unix_ms or None,
            finished_unix_ms=j.finished_unix_ms or None,
            error=j.error or None,
            stage=j.stage,
            eta_s=j.eta_ms / 1e3 if j.eta_ms else None,
        )


@dataclass(frozen=True)
class WorkerInfo:
    """A worker as the coordinator lists it (`sylva workers --json`)."""

    addr: str
    adapter: str
    #: Whether its last heartbeat was answered.
    alive: bool
    busy_strips: int
    strips_done: int
    strips_failed: int
    gpu_memory_bytes: int
    #: Hashes of the scene bundles it holds.
    cached_scenes: tuple[str, ...]
    #: Whether its adapter offers ray queries; the traversal its latest
    #: preparation chose, and why.
    ray_queries: bool
    backend: str
    backend_why: str

    @classmethod
    def from_proto(cls, w: _cpb.WorkerInfo) -> WorkerInfo:
        """The worker a wire `WorkerInfo` describes."""
        return cls(
            addr=w.addr,
            adapter=w.adapter,
            alive=w.alive,
            busy_strips=w.busy_strips,
            strips_done=w.strips_done,
            strips_failed=w.strips_failed,
            gpu_memory_bytes=w.gpu_memory_bytes,
            cached_scenes=tuple(w.cached_scenes),
            ray_queries=w.ray_queries,
            backend=w.backend,
            backend_why=w.backend_why,
        )


def load_token(
    token: str | None = None, token_file: str | os.PathLike[str] | None = None
) -> str | None:
    """The bearer token, from where the CLI takes it, in its order: the
    argument, the environment variable ``SYLVA_TOKEN``, a file (trailing
    whitespace trimmed). Empty values count as none."""
    if token:
        return token
    env = os.environ.get("SYLVA_TOKEN")
    if env:
        return env
    if token_file is not None:
        return Path(token_file).read_text().rstrip() or None
    return None


def _unprintable(c: str) -> bool:
    """Characters the coordinator refuses in names: control characters
    and bidirectional formatting ones."""
    return unicodedata.category(c) == "Cc" or c in (
        "\u061c\u200e\u200f\u202a\u202b\u202c\u202d\u202e\u2066\u2067\u2068\u2069"
    )


def _cut(s: str, most: int) -> str:
    """`s` without the characters the coordinator refuses, cut at a
    character to at most `most` UTF-8 bytes (the CLI's `cut`)."""
    out, n = [], 0
    for c in s:
        if _unprintable(c):
            continue
        size = len(c.encode("utf-8", "surrogatepass"))
        if n + size > most:
            break
        out.append(c)
        n += size
    return "".join(out)


def _submitter() -> str:
    """Who submits, for listings: ``$SYLVA_USER``, else the login name."""
    for v in ("SYLVA_USER", "USER", "LOGNAME"):
        if os.environ.get(v):
            return os.environ[v]
    return ""


def _job_id(job: str | JobSummary | JobEvent) -> str:
    return job if isinstance(job, str) else job.id


def _has_sequence(scene_path: Path) -> bool:
    try:
        scene = json.loads(scene_path.read_text())
    except (OSError, ValueError):
        return False  # packing says what is wrong
    return isinstance(scene, dict) and scene.get("sequence") is not None


def _host_port(address: str) -> tuple[str, int]:
    """`address` as ``(host, port)``; a URL or an address without a port is
    refused at once, with the form it takes."""
    if "://" in address:
        raise ValueError(
            f"{address!r}: give the coordinator as host:port, without a scheme "
            f"(e.g. {address.split('://', 1)[1].rstrip('/')!r})"
        )
    host, sep, port = address.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 < int(port) < 65536:
        raise ValueError(
            f"{address!r}: give the coordinator as host:port (its gRPC port, "
            "50150 unless it was started with another)"
        )
    return host.strip("[]"), int(port)


def _connect(channel: grpc.Channel, timeout: float) -> str | None:
    """Waits until `channel` is connected (None), or it fails to connect
    ("failed": a refused connection, or a peer that does not speak gRPC,
    is known at once), or `timeout` seconds pass (a sentence saying so)."""
    done = threading.Event()
    state: list[grpc.ChannelConnectivity] = []

    def heard(s: grpc.ChannelConnectivity) -> None:
        if s in (grpc.ChannelConnectivity.READY, grpc.ChannelConnectivity.TRANSIENT_FAILURE):
            state.append(s)
            done.set()

    channel.subscribe(heard, try_to_connect=True)
    try:
        if not done.wait(timeout):
            return f"no answer within {timeout:g} s"
    finally:
        channel.unsubscribe(heard)
    return None if state[0] == grpc.ChannelConnectivity.READY else "failed"


def _why_not_grpc(host: str, port: int) -> str:
    """Why a gRPC connection to `host:port` failed, in a user's words."""
    try:
        with socket.create_connection((host, port), timeout=2):
            pass
    except ConnectionRefusedError:
        return "connection refused (is the coordinator running, and is this its gRPC port?)"
    except OSError as e:
        return str(e.strerror or e)
    return (
        "something answers there, but not the coordinator's gRPC (the dashboard's HTTP "
        "port? a TLS port without tls_ca?)"
    )


class Client:
    """A connection to the coordinator at `address` (``host:port``).

    `token`: the bearer token sent with every call; None: ``SYLVA_TOKEN``,
    else `token_file`'s, as the CLI finds it (`load_token`). `tls_ca`: a
    CA certificate (PEM) to connect over TLS and check the coordinator
    against; `tls_domain`: the name to check in its certificate (default:
    the host dialled). The connection is made at once, within
    `connect_timeout` seconds (None: lazily, at the first call); a refused
    connection, or a port that does not speak gRPC, fails at once, and an
    address that is not ``host:port`` (a URL) raises ValueError.

    Every failed call raises `SylvaError` with its gRPC code and the
    coordinator's message. Use as a context manager, or `close()`.
    """

    def __init__(
        self,
        address: str,
        token: str | None = None,
        tls_ca: str | os.PathLike[str] | None = None,
        *,
        tls_domain: str | None = None,
        token_file: str | os.PathLike[str] | None = None,
        connect_timeout: float | None = 10.0,
    ) -> None:
        self.address = address
        host, port = _host_port(address)
        token = load_token(token, token_file)
        # gRPC sends only printable ASCII in a text header; refuse others
        # here rather than let the call fail obscurely.
        if token is not None and not all(" " <= c <= "~" for c in token):
            raise ValueError("the bearer token must be printable ASCII")
        self._metadata: tuple[tuple[str, str], ...] = (
            (("authorization", f"Bearer {token}"),) if token else ()
        )
        options: list[tuple[str, Any]] = [
            ("grpc.max_send_message_length", MAX_MESSAGE),
            ("grpc.max_receive_message_length", MAX_MESSAGE),
        ]
        if tls_ca is not None:
            ca = Path(tls_ca).read_bytes()
            if b"-----BEGIN " not in ca:
                raise ValueError(f"{tls_ca}: the CA certificate is not PEM (no -----BEGIN line)")
            if tls_domain:
                options.append(("grpc.ssl_target_name_override", tls_domain))
            creds = grpc.ssl_channel_credentials(root_certificates=ca)
            self._channel = grpc.secure_channel(address, creds, options=options)
        else:
            self._channel = grpc.insecure_channel(address, options=options)
        self._stub = _cgrpc.CoordinatorStub(self._channel)
        if connect_timeout is not None:
            why = _connect(self._channel, connect_timeout)
            if why is not None:
                self._channel.close()
                if why == "failed":
                    why = _why_not_grpc(host, port)
                raise SylvaError(
                    f"cannot reach the coordinator at {address}: {why}",
                    grpc.StatusCode.UNAVAILABLE,
                ) from None

    def close(self) -> None:
        """Closes the connection."""
        self._channel.close()

    def __enter__(self) -> Client:  # noqa: PYI034 (typing.Self is 3.11+)
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # Calls -----------------------------------------------------------------

    def submit(
        self,
        scene_path: str | os.PathLike[str],
        frame: Frame | None = None,
        *,
        name: str | None = None,
        priority: int = 0,
        schedule: str = "dynamic",
        views: Sequence[View] | None = None,
        submitter: str | None = None,
    ) -> str:
        """Packs the scene at `scene_path` (as `sylva submit` does, see
        `sylva_client.bundle.pack`) and queues a job to render `frame`
        (default: `Frame()`, the CLI's defaults) of it; returns the job's id.

        `name`: a label for listings (default: the scene's path, as the CLI
        names jobs); `priority`: higher runs first; `schedule`: "dynamic"
        or "static"; `views`: one per frame of a sequence (None or empty:
        one frame of the scene's view); `submitter`: who submits, for
        listings (default: ``$SYLVA_USER``, else the login name).

        A scene with its own ``sequence`` needs its `views` given: this
        client does not expand the scene's sequence as the CLI does.
        """
        path = Path(scene_path)
        if views is None and _has_sequence(path):
            raise ValueError(
                f"{os.fspath(scene_path)}: the scene has a sequence: pass its views "
                "(this client does not expand a scene's sequence), or views=[] for one frame"
            )
        b = _bundle.pack(scene_path)
        return self.submit_bundle(
            b,
            frame,
            name=os.fspath(scene_path) if name is None else name,
            priority=priority,
            schedule=schedule,
            views=views,
            submitter=submitter,
        )

    def submit_bundle(
        self,
        bundle: _bundle.Bundle,
        frame: Frame | None = None,
        *,
        name: str = "",
        priority: int = 0,
        schedule: str = "dynamic",
        views: Sequence[View] | None = None,
        submitter: str | None = None,
    ) -> str:
        """Queues a job for a scene already packed (see `submit`); returns
        the job's id."""
        frame = Frame() if frame is None else frame
        spec = _cpb.JobSpec(
            frame=frame.to_proto(),
            schedule=SCHEDULES[_name(schedule, list(SCHEDULES), "schedule")],
            priority=priority,
            name=_cut(name, MAX_NAME),
            submitter=_cut(_submitter() if submitter is None else submitter, MAX_SUBMITTER),
            views=[v.to_proto() for v in views or ()],
        )

        def chunks() -> Iterator[_cpb.SubmitChunk]:
            # As `submit_and_follow`: the spec, hash and size first with no
            # data, then the bytes in 1 MiB chunks.
            yield _cpb.SubmitChunk(spec=spec, hash=bundle.hash, total_size=len(bundle.bytes))
            data = bundle.bytes
            for at in range(0, len(data), CHUNK):
                yield _cpb.SubmitChunk(data=data[at : at + CHUNK])

        try:
            reply = self._stub.SubmitJob(chunks(), metadata=self._metadata)
        except grpc.RpcError as e:
            raise SylvaError.from_rpc(e) from None
        return str(reply.id)

    def watch(
        self, job: str | JobSummary | JobEvent, timeout: float | None = None
    ) -> Iterator[JobEvent]:
        """The job's events as they come, its final one (done, failed or
        cancelled) last. `timeout`: seconds for the whole watch."""
        call = self._stub.WatchJob(
            _cpb.JobId(id=_job_id(job)), metadata=self._metadata, timeout=timeout
        )
        try:
            for e in call:
                event = JobEvent.from_proto(e)
                yield event
                if event.ended:
                    return
        except grpc.RpcError as e:
            raise SylvaError.from_rpc(e) from None
        finally:
            call.cancel()  # a no-op once the stream ended

    def wait(
        self,
        job: str | JobSummary | JobEvent,
        timeout: float | None = None,
        *,
        check: bool = True,
    ) -> JobEvent:
        """Follows the job to its end and returns its final event. With
        `check`, a job that ended failed or cancelled raises
        `JobFailedError` (as `sylva submit` fails)."""
        last: JobEvent | None = None
        for event in self.watch(job, timeout):
            last = event
        if last is None or not last.ended:
            raise SylvaError("the coordinator closed the job's event stream early")
        if check and last.state != JobState.DONE:
            raise JobFailedError(last)
        return last

    def fetch_bytes(
        self, job: str | JobSummary | JobEvent, format: str = "png", frame: int = 0
    ) -> bytes:
        """A finished job's image: "png" (tone-mapped) or "exr" (linear
        HDR OpenEXR, with the passes as layers); `frame` of a sequence."""
        if format not in ("png", "exr"):
            raise ValueError(f"format {format!r}: png or exr")
        try:
            reply = self._stub.FetchResult(
                _cpb.FetchRequest(id=_job_id(job), format=format, frame=frame),
                metadata=self._metadata,
            )
        except grpc.RpcError as e:
            raise SylvaError.from_rpc(e) from None
        return bytes(reply.data)

    def fetch(
        self,
        job: str | JobSummary | JobEvent,
        out: str | os.PathLike[str],
        format: str | None = None,
        frame: int = 0,
    ) -> Path:
        """Writes a finished job's image to `out` (its folder made if
        need be) and returns its path. `format`: "png" or "exr"; None: as
        `sylva fetch`, OpenEXR when `out` ends in ``.exr``, else PNG."""
        path = Path(out)
        if format is None:
            format = "exr" if path.suffix.lower() == ".exr" else "png"
        data = self.fetch_bytes(job, format, frame)
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(data)
        return path

    def jobs(self) -> list[JobSummary]:
        """Every job the coordinator knows."""
        try:
            reply = self._stub.ListJobs(_cpb.ListJobsRequest(), metadata=self._metadata)
        except grpc.RpcError as e:
            raise SylvaError.from_rpc(e) from None
        return [JobSummary.from_proto(j) for j in reply.jobs]

    def job(self, job: str | JobSummary | JobEvent) -> JobSummary:
        """One job's summary (from the list); `SylvaError` NOT_FOUND if
        the coordinator does not know it."""
        want = _job_id(job)
        for j in self.jobs():
            if j.id == want:
                return j
        raise SylvaError(f"no job {want}", grpc.StatusCode.NOT_FOUND)

    def cancel(self, job: str | JobSummary | JobEvent) -> JobSummary:
        """Cancels a queued or running job; its summary after."""
        try:
            reply = self._stub.CancelJob(_cpb.JobId(id=_job_id(job)), metadata=self._metadata)
        except grpc.RpcError as e:
            raise SylvaError.from_rpc(e) from None
        return JobSummary.from_proto(reply)

    def requeue(self, job: str | JobSummary | JobEvent) -> str:
        """Runs a failed or cancelled job again as a new job (the same scene
        and settings); the new job's id. The old job stays as it ended."""
        try:
            reply = self._stub.RequeueJob(_cpb.JobId(id=_job_id(job)), metadata=self._metadata)
        except grpc.RpcError as e:
            raise SylvaError.from_rpc(e) from None
        return str(reply.id)

    def set_priority(self, job: str | JobSummary | JobEvent, priority: int) -> JobSummary:
        """Sets a job's priority (a queued job moves in the queue)."""
        try:
            reply = self._stub.SetPriority(
                _cpb.SetPriorityRequest(id=_job_id(job), priority=priority),
                metadata=self._metadata,
            )
        except grpc.RpcError as e:
            raise SylvaError.from_rpc(e) from None
        return JobSummary.from_proto(reply)

    def workers(self) -> list[WorkerInfo]:
        """The workers, alive or not."""
        try:
            reply = self._stub.ListWorkers(_cpb.ListWorkersRequest(), metadata=self._metadata)
        except grpc.RpcError as e:
            raise SylvaError.from_rpc(e) from None
        return [WorkerInfo.from_proto(w) for w in reply.workers]
