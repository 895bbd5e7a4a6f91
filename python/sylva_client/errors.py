"""The errors a `Client` raises."""

from __future__ import annotations

from typing import TYPE_CHECKING

import grpc

if TYPE_CHECKING:
    from .client import JobEvent

__all__ = ["JobFailedError", "SylvaError"]


def _code_name(code: grpc.StatusCode) -> str:
    """A status code as the Rust CLI names it (tonic's `Code` in `{:?}`):
    ``UNAUTHENTICATED`` → ``Unauthenticated``."""
    return "".join(w.capitalize() for w in code.name.split("_"))


class SylvaError(Exception):
    """A call the coordinator refused or could not answer.

    `code` is the gRPC status code (None where no call failed, e.g. a job
    that ended badly) and `message` the server's words; `str()` reads as
    the CLI's error, e.g. ``Unauthenticated: wrong bearer token``.
    """

    def __init__(self, message: str, code: grpc.StatusCode | None = None) -> None:
        self.code = code
        self.message = message
        super().__init__(f"{_code_name(code)}: {message}" if code is not None else message)

    @classmethod
    def from_rpc(cls, e: grpc.RpcError) -> SylvaError:
        """The error for a failed call."""
        code = e.code() if hasattr(e, "code") else grpc.StatusCode.UNKNOWN
        details = e.details() if hasattr(e, "details") else str(e)
        return cls(details or "", code)


class JobFailedError(SylvaError):
    """A job that ended failed or cancelled, where done was awaited; the
    final event is `event`."""

    def __init__(self, event: JobEvent) -> None:
        self.event = event
        why = f": {event.message}" if event.message else ""
        super().__init__(f"job {event.id} {event.state.value}{why}")
