"""The WebAssembly decoder (web/): its bytes rebuild from the C core, node decodes every committed .tw file to the
Python decoder's doubles, `tetweave view` serves the viewer, and a real headless Chromium shows a decoded file.

Needs, else the tests skip saying so: node (the JS API), `pip install ziglang==0.17.1` (the rebuild),
`apt-get install chromium` + `pip install playwright` (the browser test: Playwright drives the system's Chromium,
no browser download).
"""

from __future__ import annotations

import io
import json
import os
import shutil
import subprocess
import sys
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parent.parent
WEB = REPO / "web"
WASM = WEB / "tetweave_decoder.wasm"
MODULE = WEB / "tetweave_decoder.mjs"

from tetweave_codec.web import build as web_build  # noqa: E402 (web/build.py: its pinned zig version, the build)

FILES = sorted(REPO.glob("benchmarks/results/files/*/*.tw")) + sorted(REPO.glob("tests/data/*.tw"))
LEVELS = ("control", "smoothed", "full")
SPOT = REPO / "benchmarks/results/files/spot/size-5120-sh-auto.tw"
BACKGROUND = (0x1D, 0x20, 0x26)  # the viewer's scene background (viewer.js)

# node: decode each job's file with the WebAssembly module and write positions (float64) then indices (uint32) to
# job.out; one JSON line per job on stdout. Errors are reported, not thrown, and the next job still decodes.
NODE_SCRIPT = r"""
import { writeFileSync, readFileSync } from "node:fs";
import { createDecoder } from MODULE_URL;
const jobs = JSON.parse(readFileSync(process.argv[2], "utf8"));
const decoder = await createDecoder();
for (const job of jobs) {
  const bytes = job.bytes !== undefined ? Buffer.from(job.bytes, "base64") : readFileSync(job.file);
  try {
    const t0 = performance.now();
    const mesh = decoder.decode(bytes, { level: job.level, precision: job.precision });
    const ms = performance.now() - t0;
    writeFileSync(job.out, Buffer.concat([Buffer.from(mesh.positions.buffer), Buffer.from(mesh.indices.buffer)]));
    console.log(JSON.stringify({ ok: true, vertexCount: mesh.vertexCount, faceCount: mesh.faceCount,
      type: mesh.positions.constructor.name, stats: mesh.stats, ms }));
  } catch (error) {
    console.log(JSON.stringify({ ok: false, message: error.message, status: error.status, code: error.code,
      isError: error instanceof Error }));
  }
}
"""


def node() -> str:
    path = shutil.which("node")
    if path is None:
        pytest.skip("node is not installed (apt-get install nodejs): the JavaScript decoder is not tested")
    return path


def run_node(jobs: list[dict], tmp_path: Path) -> list[dict]:
    script = tmp_path / "decode.mjs"
    script.write_text(NODE_SCRIPT.replace("MODULE_URL", json.dumps(MODULE.as_uri())))
    (tmp_path / "jobs.json").write_text(json.dumps(jobs))
    done = subprocess.run(
        [node(), str(script), str(tmp_path / "jobs.json")], capture_output=True, text=True, timeout=900
    )
    assert done.returncode == 0, done.stderr[-3000:]
    return [json.loads(line) for line in done.stdout.splitlines()]


def python_decode(data: bytes, level: str):
    """The Python reference decoder (numpy, not the C core: decoder.CORE off, as TETWEAVE_CORE=0 sets it at import)."""
    from tetweave_codec import decoder

    saved = getattr(decoder, "CORE", False)
    decoder.CORE = False
    try:
        return decoder.decode(data, level=level)
    finally:
        decoder.CORE = saved


def core_supports(data: bytes) -> bool:
    """Version 2 with the exact Delaunay: what the C core decodes (tetweave_decoder.h)."""
    from tetweave_codec.formats.tw import unpack

    f = unpack(data)
    return getattr(f, "version", 1) == 2 and getattr(f, "exact", False)


def read_mesh(path: Path, vertex_count: int, face_count: int, dtype=np.float64):
    raw = path.read_bytes()
    split = vertex_count * 3 * np.dtype(dtype).itemsize
    positions = np.frombuffer(raw[:split], dtype=dtype).reshape(-1, 3)
    indices = np.frombuffer(raw[split:], dtype=np.uint32).reshape(-1, 3)
    assert len(indices) == face_count
    return positions, indices


# ---- the module's bytes -------------------------------------------------------------------------------------


def test_committed_module_is_there_and_imports_nothing():
    data = WASM.read_bytes()
    assert data[:4] == b"\0asm"
    assert web_build.imports(data) == []  # no WASI call: the JS gives it no I/O


def test_module_rebuilds_to_the_committed_bytes(tmp_path):
    if web_build.zig_version() != web_build.ZIG_VERSION:
        pytest.skip(f"pip install ziglang=={web_build.ZIG_VERSION} rebuilds web/tetweave_decoder.wasm to compare")
    built = tmp_path / "tetweave_decoder.wasm"
    web_build.build(built)
    assert built.read_bytes() == WASM.read_bytes(), "web/tetweave_decoder.wasm is stale: run python3 web/build.py"


def test_npm_pack_lists_the_package_files(tmp_path):
    npm = shutil.which("npm")
    if npm is None:
        pytest.skip("npm is not installed (apt-get install npm): npm pack is not tested")
    done = subprocess.run(
        [npm, "pack", "--dry-run", "--json"], cwd=WEB, capture_output=True, text=True, timeout=120,
        env={**os.environ, "npm_config_cache": str(tmp_path / "npm-cache"), "npm_config_update_notifier": "false"},
    )  # fmt: skip
    assert done.returncode == 0, done.stderr[-2000:]
    (packed,) = json.loads(done.stdout)
    assert packed["name"] == "tetweave-decoder"
    names = {f["path"] for f in packed["files"]}
    assert {"tetweave_decoder.mjs", "tetweave_decoder.wasm", "tetweave_decoder.d.ts", "TWLoader.js"} <= names
    assert not any(n.startswith(("src/", "vendor/", "viewer/")) or n.endswith(".py") for n in names), names


# ---- node: the JS API against the Python decoder ------------------------------------------------------------


@pytest.mark.parametrize("file", FILES, ids=lambda p: str(p.relative_to(REPO)))
def test_node_decodes_like_python(file, tmp_path):
    data = file.read_bytes()
    supported = core_supports(data)
    levels = LEVELS if supported else ("full",)
    jobs = [{"file": str(file), "level": lv, "precision": "float64", "out": str(tmp_path / lv)} for lv in levels]
    results = run_node(jobs, tmp_path)
    if not supported:  # a file of an earlier encoder: refused with the core's message, as documented
        (r,) = results
        assert not r["ok"] and r["isError"] and r["status"] == 2 and r["code"] == "unsupported file", r
        assert r["message"], r
        return
    for level, r in zip(levels, results, strict=True):
        assert r["ok"], r
        assert r["type"] == "Float64Array"
        positions, indices = read_mesh(tmp_path / level, r["vertexCount"], r["faceCount"])
        vertices, faces = python_decode(data, level)
        assert r["stats"]["level"] == LEVELS.index(level)
        assert indices.shape == faces.shape and np.array_equal(indices.astype(np.int64), faces), level
        # every double bit for bit (view as integers: -0.0 and NaN compare too)
        assert positions.shape == vertices.shape
        assert np.array_equal(positions.view(np.uint64), np.ascontiguousarray(vertices).view(np.uint64)), level


def test_node_float32_positions_round_the_doubles(tmp_path):
    jobs = [
        {"file": str(SPOT), "level": "full", "precision": p, "out": str(tmp_path / p)} for p in ("float64", "float32")
    ]
    r64, r32 = run_node(jobs, tmp_path)
    assert r32["type"] == "Float32Array" and r64["type"] == "Float64Array"
    p64, i64 = read_mesh(tmp_path / "float64", r64["vertexCount"], r64["faceCount"])
    p32, i32 = read_mesh(tmp_path / "float32", r32["vertexCount"], r32["faceCount"], np.float32)
    assert np.array_equal(p32, p64.astype(np.float32)) and np.array_equal(i32, i64)


def test_node_errors_carry_the_core_message_and_the_decoder_goes_on(tmp_path):
    import base64

    from tetweave_codec.errors import ContainerError
    from tetweave_codec.formats.tw import unpack

    good = SPOT.read_bytes()
    bad = bytearray(good)
    bad[len(bad) // 2] ^= 0xFF  # the CRC no longer matches
    cases = [b"", b"hello, not a mesh", good[:40], bytes(bad)]
    jobs = [{"bytes": base64.b64encode(c).decode(), "level": "full", "out": str(tmp_path / f"x{i}")} for i, c in
            enumerate(cases)]  # fmt: skip
    jobs.append({"file": str(SPOT), "level": "kinda", "out": str(tmp_path / "lv")})
    jobs.append({"file": str(SPOT), "level": "control", "out": str(tmp_path / "ok")})
    results = run_node(jobs, tmp_path)
    for case, r in zip(cases, results, strict=False):
        with pytest.raises(ContainerError):
            unpack(case)  # Python refuses each too
        assert not r["ok"] and r["isError"] and r["status"] == 1 and r["code"] == "invalid file", r
        assert r["message"] and "\n" not in r["message"], r
    assert results[4]["status"] == 5 and "kinda" in results[4]["message"]
    assert results[5]["ok"] and results[5]["faceCount"] == len(python_decode(good, "control")[1])


class ViewProcess:
    """`tetweave view FILE --no-browser [ARGS]` in a subprocess; url: the page it printed. (A mesh is encoded first:
    the URL line comes after the encode's summary lines.)"""

    def __init__(self, file: Path, *args: str):
        self.process = subprocess.Popen(
            [sys.executable, "-m", "tetweave_codec.cli.main", "view", str(file), "--no-browser", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        lines = []
        for line in self.process.stdout:
            lines.append(line)
            if line.startswith("tetweave view: serving "):
                break
        assert lines and "http://127.0.0.1:" in lines[-1], "".join(lines) + self.process.stderr.read()
        self.url = lines[-1].split(" at ", 1)[1].strip()

    def stop(self) -> None:
        self.process.terminate()
        self.process.wait(timeout=10)


FUZZ_CASES = 400


def test_node_agrees_with_python_on_damaged_files(tmp_path):
    """benchmarks/fuzz.py's structure-aware mutations of small exact-Delaunay files (resealed CRC mostly, so the
    damage reaches every section): the module never traps (a trap would read "crashed"), refuses what Python
    refuses, and decodes the rest to Python's doubles."""
    import base64

    from tetweave_codec.benchmarks import fuzz
    from tetweave_codec.errors import ContainerError

    seeds = [b for _, b in fuzz.seed_files(seed=3, max_points=200, backends=("exact",) * 3)]
    cases = [fuzz.mutate(np.random.default_rng([11, i]), seeds)[1] for i in range(FUZZ_CASES)]
    jobs = [
        {"bytes": base64.b64encode(c).decode(), "level": "full", "precision": "float64", "out": str(tmp_path / f"c{i}")}
        for i, c in enumerate(cases)
    ]
    results = run_node(jobs, tmp_path)
    outcomes = {"refused": 0, "decoded": 0}
    for i, (case, r) in enumerate(zip(cases, results, strict=True)):
        assert "crashed" not in r.get("message", ""), (i, r)
        try:
            vertices, faces = python_decode(case, "full")
        except ContainerError as exc:
            assert not r["ok"] and r["status"] in (1, 2), (i, str(exc), r)
            outcomes["refused"] += 1
            continue
        if not core_supports(case):  # a mutated backend flag: an earlier encoder's file, for Python alone
            assert not r["ok"] and r["status"] == 2, (i, r)
            continue
        assert r["ok"], (i, r)
        positions, indices = read_mesh(tmp_path / f"c{i}", r["vertexCount"], r["faceCount"])
        assert np.array_equal(indices.astype(np.int64), faces), i
        assert np.array_equal(positions.view(np.uint64), np.ascontiguousarray(vertices).view(np.uint64)), i
        outcomes["decoded"] += 1
    assert outcomes["refused"] >= 10 and outcomes["decoded"] >= 10, outcomes  # both paths exercised


# ---- tetweave view: the server ------------------------------------------------------------------------------


def test_view_serves_the_page_the_module_and_the_file(tmp_path):
    import threading

    from tetweave_codec.cli.view import make_server, viewer_path

    tw = tmp_path / "my spot.tw"
    tw.write_bytes(SPOT.read_bytes())
    server = make_server(tw)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}"
    try:

        def get(path: str):
            with urllib.request.urlopen(base + path, timeout=10) as response:
                return response.headers.get("Content-Type"), response.read()

        kind, page = get(viewer_path(tw))
        assert kind.startswith("text/html") and b"viewer.js" in page
        assert get("/tetweave_decoder.wasm") == ("application/wasm", WASM.read_bytes())
        assert get("/tetweave_decoder.mjs")[0].startswith("text/javascript")
        assert get("/vendor/three/three.module.min.js")[0].startswith("text/javascript")
        assert get("/file/my%20spot.tw")[1] == SPOT.read_bytes()
        for path in ("/file/other.tw", "/../pyproject.toml", "/%2e%2e/pyproject.toml", "/vendor/"):
            with pytest.raises(urllib.error.HTTPError) as info:
                get(path)
            assert info.value.code == 404, path
    finally:
        server.shutdown()
        server.server_close()


def test_view_refuses_what_is_neither_a_tw_file_nor_a_mesh(tmp_path):
    from click.testing import CliRunner

    from tetweave_codec.cli.main import main

    text = tmp_path / "notes.txt"
    text.write_text("hello")
    result = CliRunner().invoke(main, ["view", str(text), "--no-browser"])
    assert result.exit_code == 2 and "not a .tw file nor a mesh" in result.output
    result = CliRunner().invoke(main, ["view", "--help"])
    assert result.exit_code == 0 and "--no-browser" in result.output and "default: 0" in result.output


def test_view_encodes_a_mesh_first_and_serves_its_file(tmp_path):
    import trimesh

    from tetweave_codec.decoder import decode

    mesh = tmp_path / "ball.obj"
    trimesh.creation.icosphere(subdivisions=1).export(mesh)  # 80 faces: the small-input encode (seconds)
    out = tmp_path / "ball.tw"
    view = ViewProcess(mesh, "-o", str(out))
    try:
        with urllib.request.urlopen(view.url.split("/viewer/")[0] + "/file/ball.tw", timeout=10) as response:
            served = response.read()
    finally:
        view.stop()
    assert served == out.read_bytes()
    vertices, faces = decode(served)
    assert len(faces) > 0 and np.isfinite(vertices).all()


# ---- a real browser ----------------------------------------------------------------------------------------


def chromium() -> str:
    for name in (os.environ.get("TETWEAVE_CHROMIUM"), "chromium", "chromium-browser", "google-chrome"):
        if name and shutil.which(name):
            return shutil.which(name)
    pytest.skip("no Chromium: apt-get install chromium (and pip install playwright) runs the browser test")


DROP_JS = """([name, bytes]) => {
  const transfer = new DataTransfer();
  transfer.items.add(new File([new Uint8Array(bytes)], name));
  window.dispatchEvent(new DragEvent("drop", { dataTransfer: transfer, bubbles: true, cancelable: true }));
}"""


def test_viewer_in_headless_chromium(tmp_path):
    executable = chromium()
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("pip install playwright runs the browser test (with the system's Chromium; no download)")
    from PIL import Image

    data = SPOT.read_bytes()
    faces = {level: len(python_decode(data, level)[1]) for level in ("control", "full")}
    view = ViewProcess(SPOT)
    errors: list[str] = []
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(
                executable_path=executable,
                args=["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"],
            )
            page = browser.new_page(viewport={"width": 800, "height": 600})
            page.on("pageerror", lambda exc: errors.append(str(exc)))
            page.goto(view.url)
            page.wait_for_function("document.body.dataset.state !== 'idle' && document.body.dataset.state !== "
                                   "'loading'", timeout=120_000)  # fmt: skip
            assert page.get_attribute("body", "data-state") == "ready", page.text_content("#error")
            assert int(page.get_attribute("#faces", "data-value")) == faces["full"]
            assert int(page.get_attribute("#bytes", "data-value")) == len(data)
            decode_ms = float(page.get_attribute("#ms", "data-value"))
            assert decode_ms > 0
            # the canvas shows a mesh: many pixels differ from the background
            shot = np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB")).astype(int)
            differ = np.abs(shot - np.array(BACKGROUND)).sum(axis=2) > 30
            assert differ.mean() > 0.02, f"only {differ.mean():.4f} of the pixels differ from the background"
            (tmp_path / "viewer.png").write_bytes(page.screenshot())

            # a bad file: the decoder's message on the page, and the page keeps working
            page.evaluate(DROP_JS, ["bad.tw", list(b"TWv2 but not really a file")])
            page.wait_for_function("document.body.dataset.state === 'error'", timeout=60_000)
            message = page.text_content("#error")
            assert message.startswith("cannot decode bad.tw: ") and len(message) > len("cannot decode bad.tw: ")
            page.check('input[name="level"][value="control"]')
            page.wait_for_function("document.body.dataset.state === 'ready'", timeout=60_000)
            assert int(page.get_attribute("#faces", "data-value")) == faces["control"]
            assert page.is_hidden("#error")

            # the ES module alone on the page's thread: createDecoder() finds the .wasm beside itself
            direct = page.evaluate("""async (name) => {
              const { createDecoder } = await import("/tetweave_decoder.mjs");
              const bytes = await (await fetch("/file/" + name)).arrayBuffer();
              const mesh = (await createDecoder()).decode(bytes, { level: "full" });
              return [mesh.faceCount, mesh.positions.constructor.name, mesh.indices.constructor.name];
            }""", SPOT.name)  # fmt: skip
            assert direct == [faces["full"], "Float32Array", "Uint32Array"]
            browser.close()
    finally:
        view.stop()
    assert not errors, errors
    print(f"viewer: {SPOT.name} decoded in {decode_ms:.1f} ms in the page's worker")
