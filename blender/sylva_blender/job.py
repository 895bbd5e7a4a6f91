"""A render job on the farm, without bpy: submit the exported scene,
follow it, fetch its images. Runs in a thread in the UI (its events go
through a queue to a timer on Blender's main thread), or inline in
background mode."""

from __future__ import annotations

import queue
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable


@dataclass
class Settings:
    """What the job renders and where."""

    address: str
    token: str | None
    width: int
    height: int
    spp: int = 1
    seed: int = 1
    lighting: str | None = None
    accel: str = "auto"
    passes: list[str] | str = field(default_factory=list)
    name: str = "blender"
    tls_ca: str | None = None
    #: A sequence: Blender's frame numbers, and per frame its view
    #: ({"camera": {...}, "sun_towards": [...] or None}, export.frame_views).
    #: Empty: one frame, the scene's own view.
    frames: list[int] = field(default_factory=list)
    views: list[dict[str, Any]] = field(default_factory=list)


@dataclass
class Progress:
    """One step of the job, as the UI shows it."""

    stage: str
    fraction: float = 0.0
    job: str = ""
    done: bool = False
    error: str = ""
    exr: str = ""
    png: str = ""
    stats: dict[str, Any] | None = None
    #: A sequence's frames as fetched: Blender's frame numbers, their EXRs
    #: (`exr` and `png` are the first frame's).
    frames: list[int] = field(default_factory=list)
    exrs: list[str] = field(default_factory=list)


def run(
    client_mod: Any,
    settings: Settings,
    scene_path: Path,
    out_dir: Path,
    report: Callable[[Progress], None],
    cancelled: Callable[[], bool] = lambda: False,
) -> Progress:
    """Submits, watches and fetches; calls `report` on every step and
    returns the last one (done, or with `error` set). Never raises."""
    last = Progress("connecting")
    try:
        report(last)
        frame = client_mod.Frame(
            width=settings.width, height=settings.height, spp=settings.spp, seed=settings.seed,
            lighting=settings.lighting, accel=settings.accel, passes=settings.passes,
        )
        frame.check()
        with client_mod.Client(settings.address, token=settings.token, tls_ca=settings.tls_ca) as farm:
            last = Progress("uploading the scene")
            report(last)
            views = [
                client_mod.View(camera=client_mod.Camera(**v["camera"]),
                                sun_towards=v.get("sun_towards"))
                for v in settings.views
            ]
            job = farm.submit(scene_path, frame, name=settings.name, views=views or None)
            last = Progress("queued", job=job)
            report(last)
            final = None
            for ev in farm.watch(job):
                if cancelled():
                    farm.cancel(job)
                    last = Progress("cancelled", job=job, done=True, error="cancelled")
                    report(last)
                    return last
                total = max(ev.strips_total, 1)
                frac = ev.strips_done / total if ev.strips_total else 0.0
                words = ev.stage or ev.state.value
                if ev.strips_total:
                    words = f"{words} ({ev.strips_done}/{ev.strips_total} strips"
                    words += f" of {len(views)} frames)" if views else ")"
                last = Progress(words, fraction=frac, job=job)
                report(last)
                if ev.ended:
                    final = ev
                    break
            if final is None or final.state.value != "done":
                why = (final.message if final else "") or (final.state.value if final else "lost")
                last = Progress("failed", job=job, done=True, error=f"job {job}: {why}")
                report(last)
                return last
            out_dir.mkdir(parents=True, exist_ok=True)
            if not views:
                last = Progress("fetching the image", fraction=1.0, job=job)
                report(last)
                exr = farm.fetch(job, out_dir / f"sylva-{job}.exr")
                png = farm.fetch(job, out_dir / f"sylva-{job}.png")
                last = Progress("done", fraction=1.0, job=job, done=True, exr=str(exr),
                                png=str(png), stats=final.stats)
                report(last)
                return last
            # A sequence: every frame, numbered as Blender numbers it, so
            # that the files load as an image sequence.
            exrs, pngs = [], []
            for k, number in enumerate(settings.frames):
                last = Progress(f"fetching frame {number}", fraction=1.0, job=job)
                report(last)
                base = out_dir / f"sylva-{job}-{number:04d}"
                exrs.append(str(farm.fetch(job, base.with_suffix(".exr"), frame=k)))
                pngs.append(str(farm.fetch(job, base.with_suffix(".png"), frame=k)))
            last = Progress("done", fraction=1.0, job=job, done=True, exr=exrs[0], png=pngs[0],
                            stats=final.stats, frames=list(settings.frames), exrs=exrs)
            report(last)
            return last
    except Exception as e:  # noqa: BLE001 (every error becomes a report)
        last = Progress("failed", job=last.job, done=True, error=str(e) or type(e).__name__)
        report(last)
        return last


class Background:
    """`run` in a thread; `poll()` returns the progress steps so far."""

    def __init__(self, client_mod: Any, settings: Settings, scene_path: Path, out_dir: Path):
        self.queue: queue.Queue[Progress] = queue.Queue()
        self._cancel = threading.Event()
        self.started = time.monotonic()
        self.thread = threading.Thread(
            target=run,
            args=(client_mod, settings, scene_path, out_dir, self.queue.put, self._cancel.is_set),
            daemon=True,
        )
        self.thread.start()

    def cancel(self) -> None:
        self._cancel.set()

    def poll(self) -> list[Progress]:
        out = []
        while True:
            try:
                out.append(self.queue.get_nowait())
            except queue.Empty:
                return out
