"""The Python packer against the Rust one (`sylva scene pack`): the same
scene must give the same bundle, byte for byte, and the same refusals."""

from __future__ import annotations

import json
import os
import random
import struct
import zlib
from pathlib import Path

import pytest
from conftest import EXAMPLES, run_sylva

from sylva_client import BundleError, _json, pack


def rust_pack(sylva: Path, scene: Path, out: Path) -> tuple[bytes, str]:
    """The Rust packer's bundle of `scene`, and its hash."""
    r = run_sylva(sylva, "scene", "pack", str(scene), "-o", str(out), "--json")
    assert r.returncode == 0, r.stderr
    said = json.loads(r.stdout)
    data = out.read_bytes()
    assert said["bytes"] == len(data)
    return data, said["hash"]


def rust_refusal(sylva: Path, scene: Path, out: Path) -> str:
    """What the Rust packer says when it refuses `scene`."""
    r = run_sylva(sylva, "scene", "pack", str(scene), "-o", str(out))
    assert r.returncode != 0, f"the Rust packer packed {scene}"
    return r.stderr.strip().removeprefix("error: ")


def manifest(data: bytes) -> str:
    (n,) = struct.unpack("<Q", data[8:16])
    return data[16 : 16 + n].decode()


def assert_same(sylva: Path, scene: Path, tmp_path: Path) -> bytes:
    """Packs `scene` both ways and checks the bundles are one."""
    rust, rust_hash = rust_pack(sylva, scene, tmp_path / "rust.bundle")
    b = pack(scene)
    assert manifest(b.bytes) == manifest(rust)
    assert b.bytes == rust
    assert b.hash == rust_hash
    return rust


@pytest.mark.parametrize("name", sorted(p.name for p in EXAMPLES.glob("*.json")))
def test_every_example_packs_as_the_cli_packs_it(sylva: Path, tmp_path: Path, name: str) -> None:
    scene = EXAMPLES / name
    r = run_sylva(sylva, "scene", "pack", str(scene), "-o", str(tmp_path / "b"), "--json")
    if r.returncode != 0:
        # A scene the CLI refuses, Python refuses too.
        with pytest.raises(BundleError):
            pack(scene)
        return
    assert_same(sylva, scene, tmp_path)


AWKWARD = """{
  "models": {
    "érable 🌲": { "tree": { "species": "red_maple", "triangles": 2000, "seed": 1 } },
    "q\\"uote\\\\ tab\\t ctl\\u0001 del\\u007f ls\\u2028 nul\\u0000": { "tree": { "species": "paper_birch", "triangles": 2000, "seed": 2 } }
  },
  "instances": [
    { "model": "érable 🌲", "position": [1e-7, 1e16, 0.1], "rotate_y_deg": -0.0, "scale": 3.0 },
    { "model": "érable 🌲", "position": [1.5e300, 2.5e-308, 123456789012345680.0] },
    { "model": "érable 🌲", "position": [5e-324, 1E2, -0] },
    { "model": "érable 🌲", "position": [0.0001, 0.00001, 1e15] },
    { "model": "érable 🌲", "position": [18446744073709551615, 18446744073709551616, -9223372036854775809] },
    { "model": "érable 🌲", "position": [1.2345678901234567890123, 0.30000000000000004, 1e23] }
  ],
  "camera": { "position": [0, 1, -5], "look_at": [0, 1, 0], "fov_y_deg": 45.5 },
  "sun": { "direction": [0, 1, 0] },
  "sky": { "zenith": [0.1, 0.2, 0.3], "horizon": [0.5, 0.5, 0.5] }
}"""


def test_awkward_floats_and_names_pack_as_the_cli_packs_them(sylva: Path, tmp_path: Path) -> None:
    scene = tmp_path / "awkward scène.json"
    scene.write_text(AWKWARD, encoding="utf-8")
    rust = assert_same(sylva, scene, tmp_path)
    m = manifest(rust)
    # The layouts the Rust side writes (serde_json through zmij).
    for written in ("1e-7", "1e+16", "0.1", "-0.0", "3.0", "1.5e+300", "2.5000000000000003e-308"):
        assert written in m, written
    assert "érable 🌲" in m and "\\u0001" in m and "\x7f" in m and "\u2028" in m


def test_random_numbers_read_and_write_as_serde_json_does(sylva: Path, tmp_path: Path) -> None:
    rng = random.Random(20260)
    literals: list[str] = []
    while len(literals) < 900:
        k = rng.random()
        if k < 0.35:
            x = struct.unpack("<d", rng.getrandbits(64).to_bytes(8, "little"))[0]
            lit = repr(x)
        elif k < 0.5:
            lit = repr(rng.choice((1, -1)) * 2.0 ** rng.randint(-1074, 1023))
        else:
            digits = "".join(rng.choice("0123456789") for _ in range(rng.randint(1, 24)))
            lit = digits.lstrip("0") or "0"
            if len(lit) > 1 and rng.random() < 0.5:
                at = rng.randint(1, len(lit) - 1)
                lit = lit[:at] + "." + lit[at:]
            if rng.random() < 0.6:
                lit += rng.choice("eE") + rng.choice(("", "+", "-")) + str(rng.randint(0, 330))
            if rng.random() < 0.3:
                lit = "-" + lit
        try:
            _json.parse_number(lit)  # in range, as serde_json reads it
        except (_json.JsonError, ValueError):
            continue
        if lit not in ("nan", "inf", "-inf"):
            literals.append(lit)
    rows = ",".join(
        '{"model":"t","position":[' + ",".join(literals[i : i + 3]) + "]}"
        for i in range(0, len(literals), 3)
    )
    scene = tmp_path / "numbers.json"
    scene.write_text(
        '{"models":{"t":{"tree":{"species":"red_maple","triangles":2000,"seed":1}}},'
        f'"instances":[{rows}],'
        '"camera":{"position":[0,1,-5],"look_at":[0,1,0]},"sun":{"direction":[0,1,0]}}'
    )
    assert_same(sylva, scene, tmp_path)


def test_float_layout() -> None:
    cases = {
        1e-7: "1e-7",
        1e16: "1e+16",
        1.5e300: "1.5e+300",
        0.0001: "0.0001",
        0.00001: "0.00001",
        1e-6: "1e-6",
        1.0: "1.0",
        -0.0: "-0.0",
        1e15: "1000000000000000.0",
        123456789012345680.0: "1.2345678901234568e+17",
        5e-324: "5e-324",
        12.34: "12.34",
    }
    for x, want in cases.items():
        assert _json.format_float(x) == want, x
    assert (
        _json.dumps(_json.loads('{"b":[1,-0,2.50],"a":"\\u00e9\\n"}'))
        == '{"a":"é\\n","b":[1,-0.0,2.5]}'
    )


def tiny_png() -> bytes:
    """A 1×1 RGB PNG."""

    def chunk(kind: bytes, data: bytes) -> bytes:
        return (
            struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
        )

    ihdr = struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0)
    return (
        b"\x89PNG\r\n\x1a\n"
        + chunk(b"IHDR", ihdr)
        + chunk(b"IDAT", zlib.compress(b"\x00\x80\x80\x80"))
        + chunk(b"IEND", b"")
    )


def write_gltf_model(folder: Path, percent: bool = True) -> None:
    """A one-triangle `.gltf` with an external buffer, an inline one, and
    an (unused) image, whose URI is percent-encoded with `percent`."""
    folder.mkdir(parents=True, exist_ok=True)
    positions = struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)
    (folder / "tri.bin").write_bytes(positions)
    (folder / ("tex 1.png" if percent else "tex1.png")).write_bytes(tiny_png())
    gltf = {
        "asset": {"version": "2.0"},
        "buffers": [
            {"uri": "tri.bin", "byteLength": 36},
            {"uri": "data:application/octet-stream;base64,AAAA", "byteLength": 3},
        ],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [
            {
                "bufferView": 0,
                "componentType": 5126,
                "count": 3,
                "type": "VEC3",
                "min": [0, 0, 0],
                "max": [1, 1, 0],
            }
        ],
        "images": [{"uri": "tex%201.png" if percent else "tex1.png"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "nodes": [{"mesh": 0}],
        "scenes": [{"nodes": [0]}],
        "scene": 0,
    }
    (folder / "tri.gltf").write_text(json.dumps(gltf, indent=1))


def gltf_scene(folder: Path, percent: bool = True) -> Path:
    """A scene with a tree (model 0) and the `.gltf` triangle (model 1,
    through a symbolic link, so packed under the real file's name)."""
    write_gltf_model(folder / "models", percent)
    os.symlink("tri.gltf", folder / "models" / "link.gltf")
    p = folder / "scene.json"
    p.write_text(
        json.dumps(
            {
                "models": {
                    "a tree": {"tree": {"species": "red_maple", "triangles": 2000, "seed": 1}},
                    "b tri": {"gltf": "./models/link.gltf"},
                },
                "instances": [
                    {"model": "a tree", "position": [0, 0, 0]},
                    {"model": "b tri", "position": [0, 1, 0], "scale": 4},
                ],
                "camera": {"position": [0, 2, -12], "look_at": [0, 2, 0]},
                "sun": {"elevation_deg": 50, "azimuth_deg": 120},
                "lighting": "local",
            }
        )
    )
    return p


def test_a_gltf_with_external_files_packs_as_the_cli_packs_it(sylva: Path, tmp_path: Path) -> None:
    scene = gltf_scene(tmp_path / "g")
    rust = assert_same(sylva, scene, tmp_path)
    m = json.loads(manifest(rust))
    # Blobs are named as the worker's reader looks for them: URIs decoded.
    assert [b["name"] for b in m["blobs"]] == ["m1/tri.bin", "m1/tex 1.png", "m1/tri.gltf"]
    assert m["scene"]["models"]["b tri"]["gltf"] == "m1/tri.gltf"


def test_a_scene_importing_a_gltf_scene_packs_as_the_cli_packs_it(
    sylva: Path, tmp_path: Path
) -> None:
    # The Blender add-on's form: a glTF scene, and what the file overrides.
    folder = tmp_path / "i"
    folder.mkdir()
    r = run_sylva(
        sylva, "scene", "export", str(EXAMPLES / "ferns.json"), "--format", "gltf",
        "--out", str(folder / "forest.glb"),
    )
    assert r.returncode == 0, r.stderr
    scene = folder / "scene.json"
    scene.write_text(json.dumps({"import": "forest.glb", "lighting": "local"}))
    rust = assert_same(sylva, scene, tmp_path)
    m = json.loads(manifest(rust))
    assert [b["name"] for b in m["blobs"]] == ["i/forest.glb"]
    assert m["scene"] == {"import": "i/forest.glb", "lighting": "local"}
    scene.write_text(json.dumps({"import": "../forest.glb"}))
    assert rust_refusal(sylva, scene, tmp_path / "b").endswith("without \"..\")")
    with pytest.raises(BundleError, match="without"):
        pack(scene)


def test_a_bare_scene_file_name_packs_from_the_current_folder(
    sylva: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    scene = gltf_scene(tmp_path / "g")
    rust, _ = rust_pack(sylva, scene, tmp_path / "rust.bundle")
    monkeypatch.chdir(scene.parent)
    assert pack("scene.json").bytes == rust


@pytest.mark.parametrize(
    "gltf",
    [
        "../outside.glb",
        "/etc/passwd",
        "models/../../outside.glb",
        "models/escape.glb",
        "missing.glb",
    ],
)
def test_files_outside_the_scene_folder_are_refused_as_the_cli_refuses_them(
    sylva: Path, tmp_path: Path, gltf: str
) -> None:
    (tmp_path / "outside.glb").write_bytes(b"glTF")
    folder = tmp_path / "s"
    (folder / "models").mkdir(parents=True)
    os.symlink(tmp_path / "outside.glb", folder / "models" / "escape.glb")
    scene = folder / "scene.json"
    scene.write_text(
        json.dumps(
            {
                "models": {"m": {"gltf": gltf}},
                "instances": [],
                "camera": {"position": [0, 1, -5], "look_at": [0, 1, 0]},
                "sun": {"direction": [0, 1, 0]},
            }
        )
    )
    said = rust_refusal(sylva, scene, tmp_path / "b")
    with pytest.raises(BundleError) as e:
        pack(scene)
    assert str(e.value) == said
    assert "is not a file inside the scene's folder" in said


@pytest.mark.parametrize(
    "uri", ["../outside.bin", "file:///etc/passwd", "%2E%2E/outside.bin", "%FF%FE", "/etc/shadow"]
)
def test_gltf_uris_leading_out_are_refused_as_the_cli_refuses_them(
    sylva: Path, tmp_path: Path, uri: str
) -> None:
    (tmp_path / "outside.bin").write_bytes(b"x" * 36)
    folder = tmp_path / "s"
    write_gltf_model(folder)
    g = json.loads((folder / "tri.gltf").read_text())
    g["buffers"][0]["uri"] = uri
    (folder / "tri.gltf").write_text(json.dumps(g))
    scene = folder / "scene.json"
    scene.write_text(
        json.dumps(
            {
                "models": {"m": {"gltf": "tri.gltf"}},
                "instances": [],
                "camera": {"position": [0, 1, -5], "look_at": [0, 1, 0]},
                "sun": {"direction": [0, 1, 0]},
            }
        )
    )
    said = rust_refusal(sylva, scene, tmp_path / "b")
    with pytest.raises(BundleError) as e:
        pack(scene)
    assert str(e.value) == said
