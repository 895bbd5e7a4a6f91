"""The Python packages the add-on needs that Blender's Python lacks:
grpcio, protobuf and blake3 (the Sylva client itself is vendored in the
add-on, under ``_vendor/``).

They are pip-installed, on request (the preferences' "Install
dependencies" button), into a folder of their own in Blender's user
scripts folder, ``scripts/sylva_deps/pyXY`` (or ``$SYLVA_BLENDER_DEPS``),
which is put on ``sys.path`` when the add-on loads. Nothing is installed
into Blender's own Python.
"""

from __future__ import annotations

import importlib
import os
import subprocess
import sys
from pathlib import Path

#: Importable names of the packages needed, and their pip names.
MODULES = {"grpc": "grpcio", "google.protobuf": "protobuf", "blake3": "blake3"}
HERE = Path(__file__).resolve().parent


def target_dir() -> Path:
    """Where the dependencies go (per Python version: wheels are)."""
    env = os.environ.get("SYLVA_BLENDER_DEPS")
    if env:
        return Path(env)
    import bpy

    base = bpy.utils.user_resource("SCRIPTS")
    return Path(base) / "sylva_deps" / f"py{sys.version_info.major}{sys.version_info.minor}"


def add_to_path() -> None:
    """Puts the dependencies' folder (and the vendored wheels' folder of a
    4.2+ extension, if any) on sys.path."""
    try:
        d = target_dir()
    except Exception:  # noqa: BLE001 (no bpy: nothing to add)
        return
    if d.is_dir() and str(d) not in sys.path:
        sys.path.append(str(d))
    importlib.invalidate_caches()


def requirements() -> list[str]:
    """The pip requirements: those the vendored client was built with
    (``_vendor/requirements.txt``, written by build-zip.sh: the protobuf
    runtime must be at least the protoc that generated its stubs), else
    the bare names."""
    f = HERE / "_vendor" / "requirements.txt"
    if f.is_file():
        reqs = [line.strip() for line in f.read_text().splitlines()]
        reqs = [r for r in reqs if r and not r.startswith("#")]
        if reqs:
            return reqs
    return list(MODULES.values())


def missing() -> list[str]:
    """The pip names of the needed packages that cannot be imported."""
    out = []
    for mod, pip_name in MODULES.items():
        try:
            importlib.import_module(mod)
        except Exception:  # noqa: BLE001 (a broken install counts as missing)
            out.append(pip_name)
    return out


def install() -> str:
    """pip-installs the requirements into `target_dir()`; pip's output.
    Raises RuntimeError with pip's words where it fails."""
    d = target_dir()
    d.mkdir(parents=True, exist_ok=True)
    py = sys.executable
    env = dict(os.environ, PIP_DISABLE_PIP_VERSION_CHECK="1")
    env.pop("PYTHONNOUSERSITE", None)
    # Blender's Python may come without pip.
    if subprocess.run([py, "-m", "pip", "--version"], capture_output=True, env=env).returncode:
        r = subprocess.run([py, "-m", "ensurepip", "--upgrade"], capture_output=True, text=True,
                           env=env)
        if r.returncode:
            raise RuntimeError(f"no pip in Blender's Python ({py}), and ensurepip failed:\n"
                               f"{r.stderr.strip()[-2000:]}")
    r = subprocess.run(
        [py, "-m", "pip", "install", "--upgrade", "--target", str(d), *requirements()],
        capture_output=True, text=True, env=env,
    )
    if r.returncode:
        raise RuntimeError(f"pip install failed:\n{(r.stderr or r.stdout).strip()[-2000:]}")
    add_to_path()
    for m in [m for m in sys.modules if m == "grpc" or m.startswith(("grpc.", "google.protobuf"))]:
        del sys.modules[m]  # a failed earlier import must not stick
    return r.stdout


def client_module():  # noqa: ANN201 (the sylva_client module)
    """The Sylva client: the vendored copy, else an installed
    ``sylva_client`` (running from the source tree). Raises ImportError
    naming what is missing."""
    add_to_path()
    gone = missing()
    if gone:
        raise ImportError(
            f"missing Python packages: {', '.join(gone)} — press \"Install dependencies\" in "
            "the Sylva add-on's preferences"
        )
    try:
        from ._vendor import sylva_client  # type: ignore[attr-defined]
    except ImportError:
        import sylva_client  # type: ignore[no-redef]
    return sylva_client
