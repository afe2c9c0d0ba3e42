"""Batch runs (tetweave_codec.runner, `tetweave encode/decode` with several inputs): input discovery, the
manifest and what a re-run skips, a worker killed mid-run, failed files that never stop the batch, and the same
bytes from every runner (single file, local processes, Ray)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path, PurePosixPath

import numpy as np
import pytest
from click.testing import CliRunner
from hypothesis import given, settings
from hypothesis import strategies as st

from tetweave_codec.cli.batch import split_ray
from tetweave_codec.cli.main import main
from tetweave_codec.decoder import decode
from tetweave_codec.errors import InputError
from tetweave_codec.runner.batch import make_tasks, run_batch
from tetweave_codec.runner.executors import LocalExecutor
from tetweave_codec.runner.inputs import Source, collect_inputs, output_paths
from tetweave_codec.runner.manifest import MANIFEST_NAME, Manifest, new_record, read_last_records

manifold3d = pytest.importorskip("manifold3d")
trimesh = pytest.importorskip("trimesh")

# Tiny fits: a few seconds each, enough to give real, decodable files.
FIT = ["--points", "256", "--iters", "4", "--quality", "fast", "--device", "cpu", "--seed", "3"]
MESHES = ("sphere.ply", "box.obj", "sub/cylinder.stl", "sub/deeper/torus.off")
BROKEN = "broken.obj"


def _save(man, path: Path) -> None:
    mesh = man.to_mesh()
    path.parent.mkdir(parents=True, exist_ok=True)
    verts = np.asarray(mesh.vert_properties[:, :3], dtype=np.float64)
    trimesh.Trimesh(verts, np.asarray(mesh.tri_verts), process=False).export(path)


def make_inputs(root: Path, broken: bool = True) -> Path:
    """Four small generated meshes in nested folders, and one file with a NaN coordinate."""
    m = manifold3d.Manifold
    shapes = [
        m.sphere(1.0, 24),
        m.cube((1.0, 2.0, 1.0), center=True),
        m.cylinder(2.0, 0.5, 0.5, 20),
        m.revolve(manifold3d.CrossSection.circle(0.35, 12).translate((1.0, 0.0)), 20),
    ]
    for name, shape in zip(MESHES, shapes, strict=True):
        _save(shape, root / name)
    if broken:
        (root / BROKEN).write_text("v nan 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    return root


def run(*args):
    return CliRunner().invoke(main, [str(a) for a in args])


def records(out: Path) -> list[dict]:
    return [json.loads(line) for line in (out / MANIFEST_NAME).read_text().splitlines()]


def tw_outputs(out: Path) -> dict[str, bytes]:
    return {p.relative_to(out).as_posix(): p.read_bytes() for p in sorted(out.rglob("*.tw"))}


# ----------------------------------------------------------------------------------------------- inputs, no fits


def test_inputs_from_directories_lists_and_files(tmp_path, monkeypatch):
    (tmp_path / "d" / "a" / "b").mkdir(parents=True)
    for rel in ("d/x.ply", "d/a/b/y.OBJ", "d/a/notes.txt", "d/.hidden.ply", "e.stl", "lst/z.off"):
        (tmp_path / rel).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / rel).write_text("")
    (tmp_path / "lst" / "list.txt").write_text("# comment\n\nz.off\n../e.stl\n")
    monkeypatch.chdir(tmp_path)
    found = collect_inputs(["d", "e.stl", "@lst/list.txt", "d/x.ply"], (".ply", ".obj", ".stl", ".off"))
    rels = [(s.path.as_posix(), s.rel.as_posix()) for s in found]
    # directory files relative to the directory (recursive, hidden and other suffixes left out); files relative
    # to the working directory; list entries relative to the list's folder, outside it: their name; each once
    assert rels == [("d/a/b/y.OBJ", "a/b/y.OBJ"), ("d/x.ply", "x.ply"), ("e.stl", "e.stl"), ("lst/z.off", "z.off")]
    outs = output_paths(found, Path("out"), ".tw")
    assert [p.as_posix() for p in outs] == ["out/a/b/y.tw", "out/x.tw", "out/e.tw", "out/z.tw"]


def test_inputs_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no input files"):
        collect_inputs([str(tmp_path / "empty")], (".ply",))
    with pytest.raises(InputError, match="cannot read the list"):
        collect_inputs([f"@{tmp_path / 'missing.txt'}"], (".ply",))
    twins = [Source(Path("a/m.ply"), PurePosixPath("m.ply")), Source(Path("b/m.obj"), PurePosixPath("m.obj"))]
    with pytest.raises(InputError, match="would both be written"):
        output_paths(twins, tmp_path, ".tw")


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(st.sampled_from(["a", "b", "c.d", "e"]), min_size=1, max_size=3), max_size=8))
def test_output_paths_are_distinct_or_refused(parts):
    """Mirroring never lets two inputs share an output: either all outputs differ or the call refuses."""
    sources = [Source(Path(*p).with_suffix(".ply"), PurePosixPath(*p).with_suffix(".ply")) for p in parts]
    try:
        outs = output_paths(sources, Path("/out"), ".tw")
    except InputError:
        assert len({tuple(Path(*p).with_suffix("").parts) for p in parts}) < len(parts)
        return
    assert len(set(outs)) == len(outs)
    assert all(o.suffix == ".tw" and o.is_relative_to("/out") for o in outs)


@pytest.mark.parametrize(
    "value,inputs,expected",
    [
        (None, ("m.ply",), (False, None, ("m.ply",))),
        ("local", ("m.ply",), (True, None, ("m.ply",))),
        ("auto", ("m.ply",), (True, "auto", ("m.ply",))),
        ("ray://head:10001", (), (True, "ray://head:10001", ())),
        ("10.0.0.1:6379", (), (True, "10.0.0.1:6379", ())),
        ("meshes/", ("m.ply",), (True, None, ("meshes/", "m.ply"))),  # `--ray meshes/`: an input, not an address
    ],
)
def test_ray_address_or_input(value, inputs, expected):
    assert split_ray(value, inputs) == expected


def test_manifest_skip_rules_and_torn_lines(tmp_path):
    man = Manifest(tmp_path)
    out = tmp_path / "a.tw"
    out.write_bytes(b"x")
    opts = {"points": 256, "quantization": (1, 2)}
    man.append(new_record(input="a.ply", output="a.tw", sha256="h1", options={"points": 256, "quantization": [1, 2]}))
    man.last["a.tw"]["status"] = "ok"
    assert man.done_before("a.tw", "h1", opts, out) is not None
    assert man.done_before("a.tw", "h2", opts, out) is None  # the input changed
    assert man.done_before("a.tw", "h1", {**opts, "points": 512}, out) is None  # other options
    assert man.done_before("b.tw", "h1", opts, out) is None  # never run
    out.unlink()
    assert man.done_before("a.tw", "h1", opts, out) is None  # output gone
    # a torn last line (power loss mid-write) is ignored, and the next record starts on its own line
    with open(man.path, "a") as fh:
        fh.write('{"output": "c.tw", "sta')
    man.append(new_record(input="d.ply", output="d.tw", status="failed", error="boom"))
    last = read_last_records(man.path)
    assert set(last) == {"a.tw", "d.tw"} and last["d.tw"]["error"] == "boom"


# ------------------------------------------------------------------------------ executors with processes killed


def small_files(tmp_path: Path, n: int, options: dict) -> tuple[Path, list]:
    """n files f0.bin... holding their own names, an output folder, and a task per file writing NAME.out."""
    src, out = tmp_path / "in", tmp_path / "out"
    src.mkdir()
    out.mkdir()
    names = [f"f{i}.bin" for i in range(n)]
    for name in names:
        (src / name).write_bytes(name.encode())
    return out, make_tasks([src / n for n in names], [out / f"{n}.out" for n in names], out, options)


def test_killed_worker_is_retried_once_and_a_second_death_fails(tmp_path):
    """Real worker processes killed with SIGKILL: the file whose worker died once is retried (alone) and
    succeeds; one that kills every worker fails after two attempts; the others of the broken pool still end ok
    and the batch goes on."""
    options = {"scratch": str(tmp_path), "die_once": ["f1.bin"], "die_always": ["f3.bin"], "sleep": 0.2}
    out, tasks = small_files(tmp_path, 5, options)
    from batch_workers import die_once

    result = {r["output"]: r for r in run_batch(tasks, die_once, LocalExecutor(2), manifest=Manifest(out))}
    assert {k: r["status"] for k, r in result.items()} == {
        "f0.bin.out": "ok",
        "f1.bin.out": "ok",
        "f2.bin.out": "ok",
        "f3.bin.out": "failed",
        "f4.bin.out": "ok",
    }
    assert result["f1.bin.out"]["attempts"] == 2
    assert result["f3.bin.out"]["attempts"] == 2 and "died 2 times" in result["f3.bin.out"]["error"]
    for name in ("f0.bin", "f1.bin", "f2.bin", "f4.bin"):
        assert (out / f"{name}.out").read_bytes() == name.encode()
    assert not (out / "f3.bin.out").exists()
    assert len(records(out)) == 5


def test_interrupt_keeps_finished_files_and_leaves_no_partial_output(tmp_path):
    """Stopping the driver mid-batch (Ctrl-C) terminates the workers; what finished is written and recorded, the
    rest has neither output nor temporary file, and the next run does only the rest."""
    out, tasks = small_files(tmp_path, 4, {"sleep": 0.5})
    from batch_workers import echo

    def stop_after_first(record, counts):
        if counts.done == 1:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_batch(tasks, echo, LocalExecutor(1), manifest=Manifest(out), progress=stop_after_first)
    assert [p.name for p in out.iterdir() if p.name != MANIFEST_NAME] == ["f0.bin.out"]
    again = run_batch(tasks, echo, LocalExecutor(2), manifest=Manifest(out))
    assert sorted((r["output"], r["status"]) for r in again) == [
        ("f0.bin.out", "skipped"),
        ("f1.bin.out", "ok"),
        ("f2.bin.out", "ok"),
        ("f3.bin.out", "ok"),
    ]


# ---------------------------------------------------------------------------------------- CLI usage errors


def assert_usage_error(result, needle: str) -> None:
    assert result.exit_code == 2, result.output
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("tetweave: error:") and needle in lines[0], lines


def test_output_path_is_checked_before_any_fit(tmp_path, monkeypatch):
    """`tetweave encode mesh.ply -o /missing/dir/x.tw` and batch outputs that cannot be written fail at once."""
    import tetweave_codec.encoder

    def no_fit(*args, **kwargs):
        raise AssertionError("the fit started before the output path was checked")

    monkeypatch.setattr(tetweave_codec.encoder, "encode", no_fit)
    make_inputs(tmp_path / "in", broken=False)
    mesh = tmp_path / "in" / "sphere.ply"
    assert_usage_error(run("encode", mesh, "-o", tmp_path / "missing" / "x.tw"), "does not exist")
    assert_usage_error(run("encode", mesh, "-o", tmp_path / "in"), "is a directory")
    assert_usage_error(run("encode", tmp_path / "in", *FIT), "need -o DIR")
    assert_usage_error(run("encode", tmp_path / "in", "-o", mesh), "is not a directory")
    assert_usage_error(run("encode", tmp_path / "in", "-o", tmp_path / "no" / "such" / "dir"), "does not exist")
    (tmp_path / "twin").mkdir()
    for name in ("m.ply", "m.obj"):
        (tmp_path / "twin" / name).write_text("")
    assert_usage_error(run("encode", tmp_path / "twin", "-o", tmp_path / "o2"), "would both be written")
    if os.geteuid() != 0:  # root writes anywhere
        locked = tmp_path / "locked"
        locked.mkdir(mode=0o500)
        assert_usage_error(run("encode", mesh, "-o", locked / "x.tw"), "cannot write")
        assert_usage_error(run("encode", tmp_path / "in", "-o", locked), "cannot write")


def test_decode_batch_usage_errors(tmp_path):
    (tmp_path / "in").mkdir()
    (tmp_path / "in" / "a.tw").write_bytes(b"")
    assert_usage_error(run("decode", tmp_path / "in", "-o", tmp_path / "out", "--format", "xyz"), "--format xyz")
    assert_usage_error(run("decode", tmp_path / "in", tmp_path / "in" / "a.tw"), "need -o DIR")
    assert not (tmp_path / "out").exists()


def test_ray_missing_is_one_line(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # `import ray` raises ImportError
    make_inputs(tmp_path / "in", broken=False)
    assert_usage_error(run("encode", tmp_path / "in", "-o", tmp_path / "out", "--ray", *FIT), "tetweave[ray]")
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------------- real batch fits


@pytest.fixture(scope="module")
def batch(tmp_path_factory):
    """The target batch: 4 small generated meshes + 1 broken file, `--jobs 2 --threads 1`."""
    root = tmp_path_factory.mktemp("batch")
    src = make_inputs(root / "in")
    out = root / "out"
    t0 = time.perf_counter()
    result = run("encode", src, "-o", out, "--jobs", "2", "--threads", "1", *FIT)
    return src, out, result, time.perf_counter() - t0


def test_batch_records_failures_and_goes_on(batch):
    src, out, result, _ = batch
    assert result.exit_code == 1, result.output
    assert "5 files: 4 ok, 0 skipped, 1 failed" in result.stdout
    assert "bytes in " in result.stdout and "median Chamfer distance" in result.stdout
    # not a terminal: plain progress lines, the last one when all are done, and one line per failed file
    assert "tetweave encode: 5/5 files (4 ok, 1 failed, 0 skipped)" in result.stderr
    assert f"tetweave encode: failed: {src / BROKEN}: has non-finite" in result.stderr
    recs = {r["output"]: r for r in records(out)}
    assert set(recs) == {"sphere.tw", "box.tw", "sub/cylinder.tw", "sub/deeper/torus.tw", "broken.tw"}
    assert recs["broken.tw"]["status"] == "failed" and "non-finite" in recs["broken.tw"]["error"]
    assert recs["broken.tw"]["error"].count("\n") == 0
    assert not (out / "broken.tw").exists()
    for key, rec in recs.items():
        if key == "broken.tw":
            continue
        assert rec["status"] == "ok" and rec["options"]["points"] == 256 and rec["options"]["threads"] == 1
        data = (out / key).read_bytes()
        assert rec["bytes"] == len(data) and rec["points"] > 0 and rec["chamfer"] > 0 and rec["seconds"] > 0
        assert len(rec["sha256"]) == 64 and rec["input_bytes"] == Path(rec["input"]).stat().st_size
        for context in ("draco_bytes", "decimate_draco_bytes"):  # the summary's classical context, or null
            assert rec[context] is None or rec[context] > 0, (key, context, rec[context])
        v, f = decode(data)
        assert len(f) > 0 and np.isfinite(v).all()
    assert not [p for p in out.rglob("*") if p.name.startswith(".")]  # no temporary files left


def test_rerun_skips_and_force_redoes_with_the_same_bytes(batch):
    src, out, _, first_s = batch
    before = tw_outputs(out)
    stamps = {k: (out / k).stat().st_mtime_ns for k in before}
    t0 = time.perf_counter()
    again = run("encode", src, "-o", out, "--jobs", "2", "--threads", "1", *FIT)
    rerun_s = time.perf_counter() - t0
    assert again.exit_code == 1  # the broken file is tried again, and fails again
    new = records(out)[5:]
    assert sorted(r["status"] for r in new) == ["failed"] + ["skipped"] * 4
    first = {r["output"]: r for r in records(out)[:5]}
    for r in new:  # a skipped file keeps what its first run measured
        if r["status"] == "skipped":
            assert [r[k] for k in ("chamfer", "draco_bytes")] == [
                first[r["output"]][k] for k in ("chamfer", "draco_bytes")
            ]
    assert {k: (out / k).stat().st_mtime_ns for k in before} == stamps  # nothing rewritten
    assert rerun_s < first_s
    # --force: every file runs again
    forced = run("encode", src, "-o", out, "--jobs", "2", "--threads", "1", "--force", *FIT)
    assert forced.exit_code == 1
    assert sorted(r["status"] for r in records(out)[10:]) == ["failed"] + ["ok"] * 4
    assert tw_outputs(out) == before  # same input, options and threads: same bytes


def test_single_file_encode_gives_the_batch_bytes(batch, tmp_path):
    import torch

    src, out, _, _ = batch
    threads = torch.get_num_threads()
    try:
        single = run("encode", src / "sub" / "cylinder.stl", "-o", tmp_path / "c.tw", "--threads", "1", "-q", *FIT)
    finally:
        torch.set_num_threads(threads)
    assert single.exit_code == 0, single.output
    assert (tmp_path / "c.tw").read_bytes() == (out / "sub" / "cylinder.tw").read_bytes()


def test_worker_killed_mid_fit_is_retried(tmp_path):
    """`tetweave encode --jobs 1` in a subprocess; its worker process is SIGKILLed while fitting: the file is
    retried in a new worker, ends ok with attempts = 2, and gives the bytes of an undisturbed run."""
    src = make_inputs(tmp_path / "in", broken=False)
    mesh = src / "sphere.ply"
    out = tmp_path / "out"
    args = ["encode", str(mesh), "-o", str(out), "--jobs", "1", "--threads", "1", *FIT]
    code = f"from tetweave_codec.cli.main import main; main({args!r})"
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    killed = None
    deadline = time.monotonic() + 60
    while killed is None and time.monotonic() < deadline and proc.poll() is None:
        for pid in _children(proc.pid):
            if "spawn_main" in _cmdline(pid):
                os.kill(pid, signal.SIGKILL)
                killed = pid
                break
        time.sleep(0.05)
    stdout, stderr = proc.communicate(timeout=300)
    assert killed is not None, "no worker process seen"
    assert proc.returncode == 0, stderr
    (rec,) = records(out)
    assert rec["status"] == "ok" and rec["attempts"] == 2
    undisturbed = run("encode", mesh, "-o", tmp_path / "ref", "--jobs", "1", "--threads", "1", *FIT)
    assert undisturbed.exit_code == 0
    assert (out / "sphere.tw").read_bytes() == (tmp_path / "ref" / "sphere.tw").read_bytes()


def _children(pid: int) -> list[int]:
    try:
        text = Path(f"/proc/{pid}/task/{pid}/children").read_text()
    except OSError:
        return []
    return [int(x) for x in text.split()]


def _cmdline(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode()
    except OSError:
        return ""


def test_ray_gives_the_local_bytes(batch, tmp_path):
    """The same batch on a real local Ray (2 CPUs) writes byte-identical files to the local runner's."""
    pytest.importorskip("ray")
    src, out, _, _ = batch
    ray_out = tmp_path / "ray"
    result = run("encode", src, "-o", ray_out, "--jobs", "2", "--threads", "1", *FIT, "--ray")
    assert result.exit_code == 1, result.output
    assert tw_outputs(ray_out) == tw_outputs(out)
    assert sorted(r["status"] for r in records(ray_out)) == ["failed"] + ["ok"] * 4


def test_options_added_later_leave_older_manifest_records_valid():
    """A manifest written before --layout and --holes existed records options without them; the same run today
    (their defaults) must give the same recorded options, and other values must not."""
    from tetweave_codec.runner.manifest import canonical
    from tetweave_codec.runner.work import LATER_OPTIONS, EncodeOptions

    today = EncodeOptions(points=2048, size=10240).as_dict()
    assert not set(LATER_OPTIONS) & set(today)
    assert EncodeOptions(**today) == EncodeOptions(points=2048, size=10240)
    kept = EncodeOptions(points=2048, holes="keep", layout="grid").as_dict()
    assert kept["holes"] == "keep" and kept["layout"] == "grid"
    assert canonical(kept) != canonical(today)
