"""Sylva's Python client: submit render jobs to a Sylva coordinator,
follow them, fetch their images.

    from sylva_client import Client, Frame

    with Client("127.0.0.1:50150") as farm:
        job = farm.submit("examples/ferns.json", Frame(width=640, height=360))
        print(farm.wait(job).stats)
        farm.fetch(job, "ferns.png")

`bundle.pack` packs a scene as `sylva submit` does, byte for byte.
"""

from .bundle import Bundle, BundleError, pack
from .client import Client, JobEvent, JobState, JobSummary, WorkerInfo, load_token
from .errors import JobFailedError, SylvaError
from .frame import ACCELS, LIGHTINGS, PASSES, Camera, Frame, View

__all__ = [
    "ACCELS",
    "LIGHTINGS",
    "PASSES",
    "Bundle",
    "BundleError",
    "Camera",
    "Client",
    "Frame",
    "JobEvent",
    "JobFailedError",
    "JobState",
    "JobSummary",
    "SylvaError",
    "View",
    "WorkerInfo",
    "load_token",
    "pack",
]
