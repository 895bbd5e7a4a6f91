"""The client against a real coordinator and worker (started by
conftest.py) over loopback gRPC: submit, watch, fetch, list, cancel,
tokens and TLS."""

from __future__ import annotations

import io
import shutil
import socket
import struct
import subprocess
import threading
import time
from pathlib import Path

import grpc
import pytest
from conftest import Farm, Proc, small_scene
from PIL import Image
from test_bundle import gltf_scene

from sylva_client import (
    Client,
    Frame,
    JobFailedError,
    JobState,
    SylvaError,
)
from sylva_client._pb.sylva.v1 import worker_pb2 as wpb

EXR_MAGIC = b"\x76\x2f\x31\x01"


def exr_size(data: bytes) -> tuple[int, int]:
    """Width and height of an OpenEXR image, from its dataWindow."""
    assert data[:4] == EXR_MAGIC, "OpenEXR magic"
    at = 8
    while data[at] != 0:
        name_end = data.index(b"\0", at)
        type_end = data.index(b"\0", name_end + 1)
        (size,) = struct.unpack("<i", data[type_end + 1 : type_end + 5])
        value = data[type_end + 5 : type_end + 5 + size]
        if data[at:name_end] == b"dataWindow":
            x0, y0, x1, y1 = struct.unpack("<4i", value)
            return x1 - x0 + 1, y1 - y0 + 1
        at = type_end + 5 + size
    raise AssertionError("no dataWindow")


def until(what: str, ok, within: float = 60.0) -> None:
    t = time.monotonic()
    while not ok():
        assert time.monotonic() - t < within, f"timed out waiting for {what}"
        time.sleep(0.05)


def test_a_job_is_submitted_watched_fetched_and_listed(
    farm: Farm, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SYLVA_USER", "alice")
    scene = small_scene(tmp_path / "scene")
    with farm.client() as c:
        job = c.submit(scene, Frame(width=64, height=48), name="small one")
        events = list(c.watch(job))
        last = events[-1]
        assert last.id == job and last.state == JobState.DONE and last.ended, last
        assert all(not e.ended for e in events[:-1])
        assert last.strips_total > 0 and last.strips_done == last.strips_total, last
        assert isinstance(last.stats, dict) and last.stats, last
        # `wait` on a finished job gives its final event at once.
        assert c.wait(job).state == JobState.DONE

        png = c.fetch(job, tmp_path / "out" / "frame.png")
        with Image.open(png) as im:
            im.load()
            assert im.size == (64, 48) and im.format == "PNG"
        exr = c.fetch(job, tmp_path / "frame.exr")  # the format from the suffix
        assert exr_size(exr.read_bytes()) == (64, 48)
        assert c.fetch_bytes(job, "exr") == exr.read_bytes()
        assert c.fetch(job, tmp_path / "x.bin", format="png").read_bytes() == png.read_bytes()

        listed = {j.id: j for j in c.jobs()}
        j = listed[job]
        assert j.state == JobState.DONE and j.name == "small one", j
        assert j.submitter == "alice@127.0.0.1", j
        assert j.strips_done == j.strips_total == last.strips_total
        assert j.frames == 1 and j.error is None
        # Ended: no stage, no estimate.
        assert j.stage == "" and j.eta_s is None, j
        assert j.submitted_unix_ms <= (j.started_unix_ms or 0) <= (j.finished_unix_ms or 0)
        # The worker did the strips and holds the scene.
        (w,) = c.workers()
        assert w.alive and w.addr == farm.workers[0].addr and w.strips_done >= j.strips_total

        with pytest.raises(SylvaError) as e:
            c.fetch_bytes("no-such-job")
        assert e.value.code == grpc.StatusCode.NOT_FOUND


def test_a_gltf_scene_with_an_external_buffer_renders(farm: Farm, tmp_path: Path) -> None:
    # (Without percent-encoded URIs: the Rust packer names their blobs
    # undecoded, and the worker looks for them decoded.)
    scene = gltf_scene(tmp_path / "g", percent=False)
    with farm.client() as c:
        job = c.submit(scene, Frame(width=32, height=24, accel="bvh"))
        assert c.wait(job, timeout=120).state == JobState.DONE
        with Image.open(io.BytesIO(c.fetch_bytes(job))) as im:
            assert im.size == (32, 24)


def exr_channels(data: bytes) -> list[str]:
    """The channel names of an OpenEXR image (its chlist attribute)."""
    at = 8
    while data[at] != 0:
        name_end = data.index(b"\0", at)
        type_end = data.index(b"\0", name_end + 1)
        (size,) = struct.unpack("<i", data[type_end + 1 : type_end + 5])
        value = data[type_end + 5 : type_end + 5 + size]
        if data[at:name_end] == b"channels":
            names, i = [], 0
            while value[i] != 0:
                end = value.index(b"\0", i)
                names.append(value[i:end].decode())
                i = end + 1 + 16  # pixel type, linear, reserved, sampling
            return names
        at = type_end + 5 + size
    raise AssertionError("no channels")


def test_passes_come_back_as_exr_layers(farm: Farm, tmp_path: Path) -> None:
    scene = small_scene(tmp_path / "scene")
    with farm.client() as c:
        plain = c.submit(scene, Frame(width=32, height=24))
        job = c.submit(scene, Frame(width=32, height=24, passes=["albedo", "direct"]))
        c.wait(plain)
        c.wait(job)
        beauty = exr_channels(c.fetch_bytes(plain, "exr"))
        layers = exr_channels(c.fetch_bytes(job, "exr"))
    # Albedo and the light split (direct brings indirect and sky, as the
    # CLI's set does, so the layers add up to the image).
    assert len(layers) > len(beauty), (beauty, layers)
    for name in ("Combined.R", "DiffCol.R", "Direct.G", "Indirect.R", "Env.B"):
        assert f"ViewLayer.{name}" in layers, (name, layers)
    assert not any("Depth" in ch for ch in layers), layers


def test_queued_and_running_jobs_are_cancelled(farm: Farm, tmp_path: Path) -> None:
    scene = small_scene(tmp_path / "scene")
    with farm.client() as c:
        # The farm runs one job at a time: a long one holds it, one queues.
        long = c.submit(scene, Frame(width=640, height=480, spp=64), name="long")
        queued = c.submit(scene, Frame(width=32, height=24), name="queued", priority=-1)
        until("the long job to run", lambda: c.job(long).state == JobState.RUNNING)
        assert c.job(queued).state == JobState.QUEUED
        # A running job says what the farm is doing for it.
        until("the long job's stage", lambda: c.job(long).stage != "")

        s = c.cancel(queued)
        assert s.id == queued and s.state == JobState.CANCELLED and s.started_unix_ms is None
        s = c.cancel(long)
        assert s.state == JobState.CANCELLED and s.started_unix_ms is not None, s

        final = c.wait(long, check=False)
        assert final.state == JobState.CANCELLED
        with pytest.raises(JobFailedError) as e:
            c.wait(queued)
        assert e.value.event.state == JobState.CANCELLED
        # No empty reason after a colon: a cancel gives none.
        assert str(e.value) == f"job {queued} cancelled", e.value
        # Cancelling an ended job changes nothing; an unknown one is refused.
        assert c.cancel(queued).state == JobState.CANCELLED
        with pytest.raises(SylvaError) as err:
            c.cancel("j-no-such-job")
        assert err.value.code == grpc.StatusCode.NOT_FOUND, err.value
        assert err.value.message == "no job j-no-such-job"
        # A cancelled job runs again as a new one, to its end; a done job is not requeued.
        again = c.requeue(queued)
        assert again != queued
        assert c.wait(again).state == JobState.DONE
        assert c.job(queued).state == JobState.CANCELLED
        with pytest.raises(SylvaError) as err:
            c.requeue(again)
        assert err.value.code == grpc.StatusCode.FAILED_PRECONDITION, err.value


REFUSED = (
    "this coordinator refused the bearer token: it is not one of this farm's, or it was "
    "revoked (check --token-file or SYLVA_TOKEN; an operator makes one with "
    "`sylva token add NAME --role ROLE`)"
)
MISSING = (
    "this coordinator needs a bearer token and the call brought none: give it with "
    "--token-file FILE or SYLVA_TOKEN (the Python client: token= or token_file=)"
)


def test_a_wrong_or_missing_token_is_refused(
    farm: Farm, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv("SYLVA_TOKEN", raising=False)
    scene = small_scene(tmp_path / "scene")
    for token, said in (("not-the-token", REFUSED), (None, MISSING)):
        with Client(farm.addr, token=token) as c:
            with pytest.raises(SylvaError) as e:
                c.jobs()
            # The code and the words `sylva` prints for them: which way the
            # token failed, and the fix.
            assert e.value.code == grpc.StatusCode.UNAUTHENTICATED
            assert e.value.message == said
            assert str(e.value) == f"Unauthenticated: {said}"
            with pytest.raises(SylvaError) as e:
                c.submit(scene, Frame(width=16, height=16))
            assert e.value.code == grpc.StatusCode.UNAUTHENTICATED


def test_the_token_comes_from_sylva_token_or_a_file(
    farm: Farm, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("SYLVA_TOKEN", farm.token)
    with Client(farm.addr) as c:
        assert isinstance(c.jobs(), list)
    # The argument comes first, as the CLI's flag does.
    with Client(farm.addr, token="wrong") as c, pytest.raises(SylvaError):
        c.jobs()
    monkeypatch.setenv("SYLVA_TOKEN", "wrong")
    with Client(farm.addr, token=farm.token) as c:
        c.jobs()
    # Then the file, trailing whitespace trimmed.
    monkeypatch.delenv("SYLVA_TOKEN")
    f = tmp_path / "token"
    f.write_text(farm.token + "\n")
    with Client(farm.addr, token_file=f) as c:
        c.jobs()


def test_bad_frames_and_scenes_are_refused_with_their_reasons(farm: Farm, tmp_path: Path) -> None:
    scene = small_scene(tmp_path / "scene")
    with farm.client() as c:
        # Checked here with the CLI's rule and words, before anything is sent.
        with pytest.raises(ValueError, match=r"spp 5000: valid range \[1, 4096\]"):
            c.submit(scene, Frame(spp=5000))
        with pytest.raises(ValueError, match=r"each side must be in \[1, 16384\]"):
            c.submit(scene, Frame(height=20000))
        with pytest.raises(ValueError, match="accel"):
            c.submit(scene, Frame(accel="warp"))
        with pytest.raises(ValueError, match="pass 'fog'"):
            c.submit(scene, Frame(passes="albedo,fog"))
        with pytest.raises(ValueError, match="denoise 'sky'"):
            c.submit(scene, Frame(denoise="sky"))
    # What a denoise reads goes with it, as the CLI adds it.
    f = Frame(denoise="indirect").to_proto()
    assert f.denoise == wpb.DENOISE_INDIRECT
    assert {wpb.Pass.Name(p) for p in f.passes} >= {"PASS_ALBEDO", "PASS_NORMAL", "PASS_INDIRECT"}
    assert Frame(denoise=True).to_proto().denoise == wpb.DENOISE_FRAME
    assert Frame().to_proto().denoise == wpb.DENOISE_OFF
    with farm.client() as c:
        # A scene the coordinator refuses: its reason, with the code.
        bad = tmp_path / "bad.json"
        bad.write_text(scene.read_text().replace('"lighting"', '"lightning"'))
        with pytest.raises(SylvaError) as e:
            c.submit(bad, Frame(width=16, height=16))
        assert e.value.code == grpc.StatusCode.INVALID_ARGUMENT, e.value
        assert "lightning" in e.value.message


def test_an_unreachable_coordinator_is_a_clear_error_at_once() -> None:
    # A refused port fails at once, not after the connect timeout.
    t = time.monotonic()
    with pytest.raises(SylvaError) as e:
        Client("127.0.0.1:1", token="t", connect_timeout=30)
    assert time.monotonic() - t < 10
    assert e.value.code == grpc.StatusCode.UNAVAILABLE
    assert str(e.value).startswith(
        "Unavailable: cannot reach the coordinator at 127.0.0.1:1: connection refused"
    ), e.value
    # A URL, or no port: the form an address takes.
    for bad in ["http://127.0.0.1:50150", "127.0.0.1", "localhost:http"]:
        with pytest.raises(ValueError, match="host:port"):
            Client(bad, token="t")


def test_a_port_that_is_not_grpc_is_named_at_once(tmp_path: Path) -> None:
    # A plain TCP server that answers nothing gRPC understands, as the
    # dashboard's HTTP port does.
    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.sendall(b"HTTP/1.1 400 Bad Request\r\nContent-Length: 0\r\n\r\n")
            conn.close()

    threading.Thread(target=serve, daemon=True).start()
    try:
        t = time.monotonic()
        with pytest.raises(SylvaError) as e:
            Client(f"127.0.0.1:{port}", token="t", connect_timeout=30)
        assert time.monotonic() - t < 10
        assert "not the coordinator's gRPC" in str(e.value), e.value
    finally:
        server.close()


def openssl(*args: str, cwd: Path) -> None:
    subprocess.run(["openssl", *args], cwd=cwd, check=True, capture_output=True)


@pytest.mark.skipif(shutil.which("openssl") is None, reason="no openssl to make certificates")
def test_tls_with_a_ca_certificate(sylva: Path, tmp_path: Path) -> None:
    # A CA, and a certificate it signs for localhost and 127.0.0.1.
    openssl("req", "-x509", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1",
            "-nodes", "-days", "1", "-subj", "/CN=Sylva test CA", "-keyout", "ca.key",
            "-out", "ca.pem", cwd=tmp_path)  # fmt: skip
    openssl("req", "-newkey", "ec", "-pkeyopt", "ec_paramgen_curve:prime256v1", "-nodes",
            "-subj", "/CN=localhost", "-keyout", "key.pem", "-out", "req.csr", cwd=tmp_path)  # fmt: skip
    (tmp_path / "ext.cnf").write_text(
        "subjectAltName=DNS:localhost,IP:127.0.0.1\nbasicConstraints=CA:FALSE\n"
    )
    openssl("x509", "-req", "-in", "req.csr", "-CA", "ca.pem", "-CAkey", "ca.key",
            "-CAcreateserial", "-days", "1", "-extfile", "ext.cnf", "-out", "cert.pem",
            cwd=tmp_path)  # fmt: skip
    coord = Proc(
        sylva,
        ["coordinator", "--listen", "127.0.0.1:0", "--ephemeral", "--token", "tls-token",
         "--tls-cert", str(tmp_path / "cert.pem"), "--tls-key", str(tmp_path / "key.pem")],
        tmp_path / "coordinator.log",
    )  # fmt: skip
    try:
        with Client(coord.addr, token="tls-token", tls_ca=tmp_path / "ca.pem") as c:
            assert c.jobs() == []
        port = coord.addr.rsplit(":", 1)[1]
        with Client(f"localhost:{port}", token="tls-token", tls_ca=tmp_path / "ca.pem",
                    tls_domain="localhost") as c:  # fmt: skip
            assert c.workers() == []
        # Without TLS the coordinator cannot be spoken to.
        with pytest.raises(SylvaError):
            Client(coord.addr, token="tls-token", connect_timeout=0.5).jobs()
    finally:
        coord.stop()
