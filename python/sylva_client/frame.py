"""What a job renders: the frame's settings and, for a sequence, its views.

`Frame` mirrors the wire's `FrameSettings` (proto/sylva/v1/worker.proto)
with the defaults `sylva submit` gives its flags
(coordinator/cli/src/flags/render.rs), and is checked with the same rules
(shared/scene/src/frame.rs, `FrameSettings::check`) before it is sent, as
the CLI checks it.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

from ._pb.sylva.v1 import coordinator_pb2 as _cpb
from ._pb.sylva.v1 import worker_pb2 as _wpb

__all__ = ["ACCELS", "LIGHTINGS", "PASSES", "SCHEDULES", "Camera", "Frame", "View"]

#: Largest image side a frame may have.
MAX_SIDE = 16_384
#: Most rays per pixel a frame may ask for.
MAX_SPP = 4_096
#: The gathers' bounce count: default and most.
DEFAULT_GATHER_BOUNCES = 1
MAX_GATHER_BOUNCES = 4
#: The gathers' filter radius in pixels: default and largest.
DEFAULT_GATHER_FILTER = 3
MAX_GATHER_FILTER = 16

#: Lighting methods by the names `--lighting` takes; "scene" (or None):
#: the scene file's own.
LIGHTINGS: dict[str, _wpb.Lighting] = {
    "scene": _wpb.LIGHTING_SCENE,
    "local": _wpb.LIGHTING_LOCAL,
    "ambient": _wpb.LIGHTING_AMBIENT,
    "lb": _wpb.LIGHTING_LB,
    "lb-visualize": _wpb.LIGHTING_LB_VISUALIZE,
    "boulanger": _wpb.LIGHTING_BOULANGER,
    "gather": _wpb.LIGHTING_GATHER,
    "gather-ambient": _wpb.LIGHTING_GATHER_AMBIENT,
    "reference": _wpb.LIGHTING_REFERENCE,
}

#: Traversals by the names `--accel` takes.
ACCELS: dict[str, _wpb.Accel] = {
    "auto": _wpb.ACCEL_AUTO,
    "rq": _wpb.ACCEL_RQ,
    "bvh": _wpb.ACCEL_BVH,
    "cwbvh": _wpb.ACCEL_CWBVH,
    "kd": _wpb.ACCEL_KD,
}

#: Render passes by the names `--passes` takes, in wire order.
PASSES: tuple[str, ...] = (
    "beauty",
    "direct",
    "indirect",
    "albedo",
    "normal",
    "depth",
    "instance",
    "species",
    "sky",
)

#: What of a frame `denoise` may name, and the passes each reads (the
#: CLI's `--denoise`): the guides, and for the indirect light alone the
#: light split.
DENOISE_PASSES: dict[str, tuple[str, ...]] = {
    "off": (),
    "frame": ("albedo", "normal"),
    "indirect": ("albedo", "normal", "indirect"),
}

#: How a frame is cut into strips, by the names `--schedule` takes.
SCHEDULES: dict[str, _cpb.Schedule] = {
    "dynamic": _cpb.SCHEDULE_DYNAMIC,
    "static": _cpb.SCHEDULE_STATIC,
}


def _name(value: str, known: Sequence[str], what: str) -> str:
    """`value` if it is one of `known` (``_`` read as ``-``), else a
    ValueError naming the valid ones."""
    v = value.strip().lower().replace("_", "-")
    if v not in known:
        raise ValueError(f"{what} {value!r}: one of {', '.join(known)}")
    return v


def pass_set(passes: str | Sequence[str] | None) -> list[str]:
    """The passes beside beauty that `passes` asks for, in wire order, as
    the CLI's `PassSet` makes them: "all" (alone or listed) is every
    pass; `beauty` is always written and so not listed; any of `direct`,
    `indirect` or `sky` brings the other two, so that the three sum to the
    beauty image. A string is read as `--passes` is, names separated by
    commas."""
    if passes is None:
        return []
    names = passes.split(",") if isinstance(passes, str) else list(passes)
    wanted: set[str] = set()
    for raw in names:
        name = raw.strip()
        if not name:
            continue
        if name == "all":
            wanted = set(PASSES)
            break
        if name not in PASSES:
            raise ValueError(f"pass {name!r}: one of {', '.join(PASSES)}, or all")
        wanted.add(name)
    wanted.discard("beauty")
    if wanted & {"direct", "indirect", "sky"}:
        wanted |= {"direct", "indirect", "sky"}
    return [p for p in PASSES if p in wanted]


def _denoise(v: bool | str) -> str:
    """The name `denoise` means: a bool (True: the whole frame) or one of
    `DENOISE_PASSES`'s names."""
    if isinstance(v, bool):
        return "frame" if v else "off"
    if not isinstance(v, str):
        raise ValueError(f"denoise {v!r}: True, False or one of {', '.join(DENOISE_PASSES)}")
    return _name(v, list(DENOISE_PASSES), "denoise")


def _three(v: Sequence[float] | None, what: str) -> list[float] | None:
    if v is None:
        return None
    values = [float(x) for x in v]
    if len(values) != 3:
        raise ValueError(f"{what}: three values, not {len(values)}")
    return values


@dataclass
class Camera:
    """A camera as the scene file gives one (``camera`` in
    docs/scene-format.md), for a view of a sequence."""

    position: Sequence[float]
    look_at: Sequence[float]
    up: Sequence[float] = (0.0, 1.0, 0.0)
    #: Vertical field of view, degrees.
    fov_y_deg: float = 40.0

    def to_proto(self) -> _wpb.CameraPose:
        """The wire's `CameraPose`."""
        return _wpb.CameraPose(
            position=_three(self.position, "camera.position"),
            look_at=_three(self.look_at, "camera.look_at"),
            up=_three(self.up, "camera.up"),
            fov_y_deg=float(self.fov_y_deg),
        )


@dataclass
class View:
    """One frame's view of the scene in a sequence: camera and sun, each
    the scene's own where None."""

    camera: Camera | None = None
    #: A vector towards the sun (three values).
    sun_towards: Sequence[float] | None = None

    def to_proto(self) -> _wpb.FrameView:
        """The wire's `FrameView`."""
        v = _wpb.FrameView(sun_towards=_three(self.sun_towards, "sun_towards") or [])
        if self.camera is not None:
            v.camera.CopyFrom(self.camera.to_proto())
        return v


@dataclass
class Frame:
    """A frame to render, with `sylva submit`'s defaults.

    `lighting`: a name from `LIGHTINGS` ("lb", "reference", ...), or None /
    "scene" for the scene file's own method. `accel`: "auto", "rq", "bvh",
    "cwbvh" or "kd". `passes`: names from `PASSES`, or "all" (written as the
    layers of the EXR; see docs/passes.md).
    """

    #: Image width and height, pixels.
    width: int = 896
    height: int = 448
    #: Rays per pixel.
    spp: int = 1
    #: Seed of the per-pixel sample positions.
    seed: int = 1
    #: Lighting method; None: the scene's.
    lighting: str | None = None
    #: How rays traverse the scene.
    accel: str = "auto"
    #: The paper LB model's weight of LB light relative to the sun's.
    lb_strength: float = 0.35
    #: The ambient method's constant, linear RGB; None: matched to the LB.
    ambient: Sequence[float] | None = None
    #: The gather methods: bounces traced before the lattice (1 to 4).
    gather_bounces: int = DEFAULT_GATHER_BOUNCES
    #: The gather methods: radius in pixels of their filter (0: none).
    gather_filter: int = DEFAULT_GATHER_FILTER
    #: Render passes beside the beauty image.
    passes: str | Sequence[str] = field(default_factory=list)
    #: Denoise the frame (Open Image Denoise on the coordinator), guided by
    #: the albedo and normal passes, which it adds: ``True`` or ``"frame"``
    #: the whole frame, ``"indirect"`` its indirect light alone (and the
    #: light split, which that reads). The EXR keeps the noisy image as its
    #: "Noisy Image" layer.
    denoise: bool | str = False

    def check(self) -> None:
        """Raises ValueError, with the CLI's words, for a frame the farm
        would refuse."""
        for name in ("width", "height", "spp", "seed", "gather_bounces", "gather_filter"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not 0 <= v < 1 << 32:
                raise ValueError(f"{name} {v!r}: an integer in [0, 2^32)")
        if not (1 <= self.width <= MAX_SIDE and 1 <= self.height <= MAX_SIDE):
            raise ValueError(
                f"image {self.width}×{self.height}: each side must be in [1, {MAX_SIDE}]"
            )
        if not 1 <= self.spp <= MAX_SPP:
            raise ValueError(f"spp {self.spp}: valid range [1, {MAX_SPP}]")
        if not (math.isfinite(self.lb_strength) and self.lb_strength >= 0):
            raise ValueError(f"lb_strength {self.lb_strength}: must be a finite number ≥ 0")
        if not 1 <= self.gather_bounces <= MAX_GATHER_BOUNCES:
            raise ValueError(
                f"gather_bounces {self.gather_bounces}: valid range [1, {MAX_GATHER_BOUNCES}]"
            )
        if self.gather_filter > MAX_GATHER_FILTER:
            raise ValueError(
                f"gather_filter {self.gather_filter}: valid range [0, {MAX_GATHER_FILTER}]"
            )
        a = _three(self.ambient, "ambient")
        if a is not None and not all(math.isfinite(x) and x >= 0 for x in a):
            raise ValueError(f"ambient {a}: three finite values ≥ 0")
        if self.lighting is not None:
            if self.lighting.strip().lower() == "auto":
                # As `sylva submit` says: auto picks a method on the local GPU.
                raise ValueError(
                    "lighting auto runs its pilot on this machine's GPU: "
                    "`sylva render --local-workers 0 --lighting auto …`"
                )
            _name(self.lighting, list(LIGHTINGS), "lighting")
        _name(self.accel, list(ACCELS), "accel")
        pass_set(self.passes)
        _denoise(self.denoise)

    def to_proto(self) -> _wpb.FrameSettings:
        """The wire's `FrameSettings` (checked first)."""
        self.check()
        lighting = "scene" if self.lighting is None else _name(self.lighting, list(LIGHTINGS), "")
        f = _wpb.FrameSettings(
            width=self.width,
            height=self.height,
            spp=self.spp,
            seed=self.seed,
            lighting=LIGHTINGS[lighting],
            accel=ACCELS[_name(self.accel, list(ACCELS), "")],
            lb_strength=float(self.lb_strength),
            ambient=_three(self.ambient, "ambient") or [],
            gather_bounces=self.gather_bounces,
            gather_filter=self.gather_filter,
        )
        passes = pass_set(self.passes)
        denoise = _denoise(self.denoise)
        if denoise != "off":
            passes = pass_set([*passes, *DENOISE_PASSES[denoise]])
            f.denoise = _wpb.Denoise.Value(f"DENOISE_{denoise.upper()}")
        if passes:
            # An older proto without passes cannot ask for them.
            if "passes" not in _wpb.FrameSettings.DESCRIPTOR.fields_by_name:
                raise ValueError("this client's protocol has no render passes")
            f.passes.extend(_wpb.Pass.Value(f"PASS_{p.upper()}") for p in passes)
        return f
