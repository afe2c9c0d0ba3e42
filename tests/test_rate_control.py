"""Rate control: --size and --max-error are honoured on small shapes; impossible targets fail cleanly."""

from __future__ import annotations

import numpy as np
import pytest
from click.testing import CliRunner

from tetweave_codec import rate_control
from tetweave_codec.cli.main import main
from tetweave_codec.decoder import decode
from tetweave_codec.encoder import encode
from tetweave_codec.errors import InputError
from tetweave_codec.formats.quantize import default_quantization
from tetweave_codec.job import FitSettings, make_job
from tetweave_codec.rate_control import error as rc_error
from tetweave_codec.rate_control import size as rc_size

manifold3d = pytest.importorskip("manifold3d")

FAST = {"quality": "fast", "iters": 40, "device": "cpu", "seed": 0}


@pytest.fixture
def search_only(monkeypatch):
    """The --max-error search alone (no feature-only fit first: these tests pass no job)."""
    monkeypatch.setattr(rc_error, "_feature_only_trial", lambda job, max_error: None)


def _mesh(m) -> tuple[np.ndarray, np.ndarray]:
    mesh = m.to_mesh()
    return np.asarray(mesh.vert_properties[:, :3], dtype=np.float64), np.asarray(mesh.tri_verts, dtype=np.int64)


def csg_shape() -> tuple[np.ndarray, np.ndarray]:
    box = manifold3d.Manifold.cube((2.0, 1.4, 1.0), center=True)
    bite = manifold3d.Manifold.sphere(0.8, 48).translate((1.0, 0.7, 0.5))
    return _mesh(box - bite)


def sphere() -> tuple[np.ndarray, np.ndarray]:
    return _mesh(manifold3d.Manifold.sphere(1.0, 48))


def test_size_model_is_monotonic_and_inverts():
    sizes = [500, 2000, 8000, 32000, 128000]
    points = [rate_control.points_for_size(s) for s in sizes]
    assert points == sorted(points) and len(set(points)) == len(points)
    for s, n in zip(sizes, points, strict=True):
        assert n * rate_control.bytes_per_point(n) == pytest.approx(rate_control.SIZE_AIM * s, rel=0.02)


def test_step_factor_refines_only_accurate_inputs_at_large_counts():
    """k = 1 (the default steps) from the knee of the detail measure up, for an unknown one and below the ramp's
    first count; MIN_STEP_FACTOR for a piecewise-flat input (D = 0) from the ramp's last count; monotonic between."""
    lo, hi = rate_control.PRECISION_RAMP_POINTS
    knee = rate_control.PRECISION_KNEE
    assert rate_control.step_factor(knee, 10 * hi) == 1.0
    assert rate_control.step_factor(knee + 1.0, 10 * hi) == 1.0
    assert rate_control.step_factor(float("inf"), 10 * hi) == 1.0
    assert rate_control.step_factor(0.0, lo) == 1.0
    assert rate_control.step_factor(0.0, hi) == pytest.approx(rate_control.MIN_STEP_FACTOR)
    assert rate_control.step_factor(0.0, 10 * hi) == pytest.approx(rate_control.MIN_STEP_FACTOR)
    by_count = [rate_control.step_factor(0.5, int(n)) for n in np.geomspace(lo / 2, 2 * hi, 12)]
    assert by_count == sorted(by_count, reverse=True) and by_count[0] > by_count[-1]
    by_detail = [rate_control.step_factor(d, hi) for d in np.linspace(0.0, 2.0, 9)]
    assert by_detail == sorted(by_detail) and by_detail[0] < by_detail[4] < by_detail[-1]


def test_finer_steps_are_paid_for_with_points():
    """An accurate input (D = 0) gets fewer points at large sizes (finer steps cost bytes) and the same at small
    ones; its grid is never coarser than the default steps' point count would have; a detailed one is unchanged."""
    for size in (2000, 5000, 10000):
        assert rate_control.points_for_size(size, 0.0) == rate_control.points_for_size(size)
    for size in (20000, 40000, 80000):
        fine, plain = rate_control.points_for_size(size, 0.0), rate_control.points_for_size(size)
        assert 0.7 * plain < fine < plain
        assert rate_control.points_for_size(size, 3.0) == plain
        q, q_plain = rate_control.size_quantization(fine, size, 0.0), default_quantization(plain)
        assert q.position_bits >= q_plain.position_bits
        expected = default_quantization(fine).s_step * rate_control.step_factor(0.0, fine)
        assert q.s_step == pytest.approx(expected) and q.s_step < default_quantization(fine).s_step
        assert rate_control.size_quantization(plain, size, 3.0) == q_plain


def test_input_detail_is_measured_once_per_job(monkeypatch):
    """The decimation probe runs once per job; rate control's prior and steps read the same value."""
    import fast_simplification

    calls = []
    real = fast_simplification.simplify
    monkeypatch.setattr(fast_simplification, "simplify", lambda *a: calls.append(1) or real(*a))
    job = make_job(*bumpy_sphere(), FitSettings(1, None))
    first = rate_control.input_detail(job)
    assert rate_control.input_detail(job) == first and job.input.detail == first and len(calls) == 1
    assert rate_control.prior_error_points(job) == pytest.approx(
        rate_control.PRIOR_BASE + rate_control.PRIOR_DETAIL_SLOPE * max(0.0, first - rate_control.PRIOR_DETAIL_KNEE)
    )
    assert len(calls) == 1


@pytest.mark.parametrize("size", [2500, 6000])
def test_size_target_lands_in_the_band(size):
    v, f = csg_shape()
    result = encode(v, f, size=size, **FAST)
    assert rate_control.SIZE_FLOOR * size <= len(result.data) <= size
    assert result.stats["target_bytes"] == size and result.stats["bytes"] == len(result.data)
    dv, df = decode(result.data)
    np.testing.assert_array_equal(dv, result.vertices)
    np.testing.assert_array_equal(df, result.faces)


def test_max_error_target_is_met():
    v, f = sphere()
    # 40-iteration fits are noisy near their floor: 4e-3 was reached at 3.96e-3 with TetGen's triangulation and
    # missed (4.1e-3) with the exact Delaunay's; the contract (error <= target) is what is tested
    target = 5e-3
    result = encode(v, f, max_error=target, **FAST)
    assert result.stats["chamfer"] <= target
    assert result.stats["target_error"] == target
    dv, df = decode(result.data)
    np.testing.assert_array_equal(df, result.faces)


@pytest.mark.parametrize(
    "options,needle",
    [
        ({"size": 50}, "below the smallest"),
        ({"size": 10**9}, "use --points"),
        ({"max_error": 1e-9}, "out of reach"),
        ({"size": 5000, "max_error": 1e-3}, "either"),
        ({"size": 5000, "container_version": 1}, "version 2"),
    ],
)
def test_impossible_targets_are_rejected(options, needle):
    v, f = sphere()
    with pytest.raises(InputError, match=needle):
        encode(v, f, **{**FAST, **options})


def test_cli_size_reports_target(tmp_path):
    import trimesh

    v, f = csg_shape()
    src = tmp_path / "part.ply"
    trimesh.Trimesh(v, f, process=False).export(src)
    out = tmp_path / "part.tw"
    res = CliRunner().invoke(main, ["encode", str(src), "-o", str(out), "--size", "4k", "--iters", "40", "-q"])
    assert res.exit_code == 0, res.output
    assert "size target 4,096 bytes" in res.output
    assert 0.85 * 4096 <= out.stat().st_size <= 4096


@pytest.mark.parametrize("k,floor", [(1.0, 0.0), (3.5, 0.0), (12.0, 0.0), (2.0, 3e-4)])
def test_max_error_search_on_a_model_of_the_error(search_only, monkeypatch, k, floor):
    """The search over point counts (fits replaced by err = k / N + floor): it meets the target within
    MAX_ERROR_FITS fits and ends close to the smallest sufficient count, or refuses in one line."""
    calls = []

    def fake_fit(job, n, quant):
        calls.append(n)
        return rate_control.Trial(None, None, b"", k / n + floor, None)

    monkeypatch.setattr(rc_error, "_fit_and_measure", fake_fit)
    monkeypatch.setattr(rc_error, "mesh_prior", lambda job: (rate_control.PRIOR_ERROR_POINTS, 0.0))
    monkeypatch.setattr(rc_error, "_smallest_within", lambda job, run, e, n, note: (n, run.error))
    target = 1e-3
    needed = k / (target - floor)
    if needed > rate_control.MAX_RATE_POINTS:
        with pytest.raises(InputError, match="reach"):
            rate_control.encode_to_error(None, target)
        return
    n, err = rate_control.encode_to_error(None, target)
    assert err <= target and len(calls) <= rate_control.MAX_ERROR_FITS
    assert n <= 1.7 * needed  # not far above the smallest count that meets the target


def test_max_error_search_on_a_holed_mesh_does_not_overshoot(search_only, monkeypatch):
    """A holed input whose prior over-counts (P = 4.05 with the hole caps' F = 4.3e-4, true err = 3.1 / N + F,
    stanford-bunny's numbers): the file must not be sized by P / (aim - F), which lands far below the target with
    ~1.6x the points needed."""
    calls = []

    def fake_fit(job, n, quant):
        calls.append(n)
        return rate_control.Trial(None, None, b"", 3.1 / n + 4.3e-4, None)

    monkeypatch.setattr(rc_error, "_fit_and_measure", fake_fit)
    monkeypatch.setattr(rc_error, "mesh_prior", lambda job: (4.05, 4.3e-4))
    monkeypatch.setattr(rc_error, "_smallest_within", lambda job, run, e, n, note: (n, run.error))
    n, err = rate_control.encode_to_error(None, 1e-3)
    assert err <= 1e-3 and len(calls) <= rate_control.MAX_ERROR_FITS
    assert n <= 1.25 * 3.1 / (1e-3 - 4.3e-4)


def test_max_error_search_refuses_what_no_allowed_fit_reaches(search_only, monkeypatch):
    monkeypatch.setattr(rc_error, "mesh_prior", lambda job: (rate_control.PRIOR_ERROR_POINTS, 0.0))
    monkeypatch.setattr(rc_error, "_fit_and_measure", lambda job, n, q: rate_control.Trial(None, None, b"", 5e-3, None))
    with pytest.raises(InputError, match="could not reach|out of reach"):
        rate_control.encode_to_error(None, 1e-3)


def bumpy_sphere() -> tuple[np.ndarray, np.ndarray]:
    """A sphere with fine radial bumps (detail a 1000-vertex decimation cannot hold)."""
    v, f = _mesh(manifold3d.Manifold.sphere(1.0, 160))
    u = v / np.linalg.norm(v, axis=1, keepdims=True)
    bumps = 1.0 + 0.03 * np.sin(23 * u[:, 0]) * np.sin(19 * u[:, 1]) * np.sin(17 * u[:, 2])
    return v * bumps[:, None], f


def test_prior_grows_with_detail_the_decimation_misses():
    """The per-mesh prior: a smooth sphere gets the base N x Chamfer, a bumpy one (same size) more; the same mesh
    gives the same prior (the decimation and its Chamfer samples are deterministic)."""

    def prior(v, f):
        return rate_control.prior_error_points(make_job(v, f, FitSettings(1, None)))

    smooth = prior(*_mesh(manifold3d.Manifold.sphere(1.0, 160)))
    bumpy = prior(*bumpy_sphere())
    assert smooth == pytest.approx(rate_control.PRIOR_BASE)
    assert bumpy > smooth + 0.5
    assert prior(*bumpy_sphere()) == bumpy


@pytest.mark.parametrize("option,needle", [(["--size", "50"], "smallest"), (["--max-error", "1e-9"], "out of reach")])
def test_cli_target_out_of_reach_exits_2_without_output(tmp_path, option, needle):
    """An impossible --size or --max-error: one line, exit 2, no file written."""
    import trimesh

    v, f = sphere()
    src = tmp_path / "ball.ply"
    trimesh.Trimesh(v, f, process=False).export(src)
    out = tmp_path / "ball.tw"
    res = CliRunner().invoke(main, ["encode", str(src), "-o", str(out), *option])
    assert res.exit_code == 2
    assert "Traceback" not in res.output and needle in res.output
    if option[0] == "--max-error":
        assert len(res.output.strip().splitlines()) == 1
    assert not out.exists()


def test_hole_cap_error_of_a_hemisphere():
    """F of the prior: 0 for a closed mesh; a unit hemisphere's one hole (a disc of radius 1, area pi) sits 1/3
    from its rim on average: F = 0.5 * pi / 3 / (2 pi) = 1/12."""
    v, f = _mesh(manifold3d.Manifold.sphere(1.0, 256))
    assert rate_control.hole_cap_error(v, f) == 0.0
    centres = v[f].mean(axis=1)
    upper = f[centres[:, 2] > 0]
    assert rate_control.hole_cap_error(v, upper) == pytest.approx(1 / 12, rel=0.05)


@pytest.mark.parametrize("floor,needle", [(4.5e-4, "holes"), (0.0, "points for it by its prior")])
def test_max_error_beyond_the_prior_is_refused_before_any_fit(search_only, monkeypatch, floor, needle):
    """A target the per-mesh prior puts beyond MAX_RATE_POINTS (or below the hole caps' error) is refused with one
    line before any fit; the holes are named only when the input has some."""
    monkeypatch.setattr(rc_error, "mesh_prior", lambda job: (2.0, floor))
    monkeypatch.setattr(rc_error, "_fit_and_measure", lambda *a: pytest.fail("no fit expected"))
    with pytest.raises(InputError, match="out of reach") as info:
        rate_control.encode_to_error(None, 5e-4 if floor else 2e-5)
    assert needle in str(info.value) and "\n" not in str(info.value)
    assert ("holes" in str(info.value)) == (floor > 0)


def test_choose_keeps_the_steps_balanced_before_the_default_grid(monkeypatch):
    """`choose`: the default grid at steps up to BALANCED_STEP_SCALE x the default first, then another grid
    within that, then the rule before (default grid up to x2.0, else the largest estimate under the aim, else the
    smallest file)."""
    from tetweave_codec.formats.quantize import default_quantization
    from tetweave_codec.rate_control import BALANCED_STEP_SCALE, SIZE_AIM, Candidate, choose

    assert BALANCED_STEP_SCALE == 1.4
    base = default_quantization(9479)  # b 9
    size = 20480
    aim = SIZE_AIM * size

    def cands(*rows):
        return [Candidate(int(est), bits, scale, None) for bits, scale, est in rows]

    def pick(rows):
        chosen = choose(cands(*rows), base, size)
        return chosen.position_bits, chosen.scale

    # igea 20 KB: the default grid fits only at x2.8 (and x2.0 just over the aim); b 8 fits at x1
    rows = [(9, 2.8, aim - 600), (9, 2.0, aim + 400), (9, 1.4, aim + 1300), (8, 1.0, aim - 700), (8, 0.7, aim + 1000)]
    assert pick(rows) == (8, 1.0)
    monkeypatch.setattr(rc_size, "BALANCED_STEP_SCALE", None)  # the rule before: the default grid first
    assert pick(rows) == (9, 2.8)
    monkeypatch.undo()
    # the default grid fitting within the balanced steps wins over a coarser grid with a larger estimate
    assert pick([(9, 1.4, aim - 900), (8, 1.0, aim - 100)]) == (9, 1.4)
    # nothing within the balanced steps: the default grid up to x2.0, then the largest estimate under the aim
    assert pick([(9, 2.0, aim - 50), (8, 2.8, aim - 10), (9, 1.4, aim + 5)]) == (9, 2.0)
    assert pick([(9, 2.8, aim - 50), (8, 2.8, aim - 10)]) == (8, 2.8)
    assert pick([(9, 2.8, aim + 50), (8, 2.8, aim + 10)]) == (8, 2.8)  # none fits: the smallest


def test_feature_only_fit_meets_a_tight_target_on_a_cube():
    """--max-error on a cube: the feature-only fit (64 points, its start exact) holds the cube to 1e-4 in under
    500 bytes (measured 186 B at 7.2e-5; the search over point counts sized it at ~13K points); closed, manifold,
    decoded exactly as reported."""
    v, f = _mesh(manifold3d.Manifold.cube((1.0, 1.0, 1.0), center=True))
    result = encode(v, f, max_error=1e-4, device="cpu", seed=0)
    assert "feature-only" in result.stats["rate_control"]
    assert len(result.data) <= 500 and result.stats["chamfer"] <= 1e-4
    dv, df = decode(result.data)
    np.testing.assert_array_equal(dv, result.vertices)
    np.testing.assert_array_equal(df, result.faces)
    solid = manifold3d.Manifold(manifold3d.Mesh(dv.astype(np.float32), df.astype(np.uint32)))
    assert solid.status() == manifold3d.Error.NoError and not solid.is_empty()


def test_feature_only_fit_is_not_tried_where_its_start_is_far(monkeypatch):
    """Three boxes (start at 64 points ~8e-2 from the input) and a sphere (no creases): no feature-only fit runs."""

    monkeypatch.setattr(rc_error, "_fit_and_measure", lambda *a, **k: pytest.fail("no fit expected"))
    boxes = _mesh(
        manifold3d.Manifold.cube((1.2, 0.4, 0.4), center=True)
        + manifold3d.Manifold.cube((0.4, 1.2, 0.4), center=True)
        + manifold3d.Manifold.cube((0.4, 0.4, 1.2), center=True).translate((0.3, 0.2, 0.1))
    )
    for v, f in (boxes, sphere()):
        job = make_job(v, f, FitSettings(-1, None))
        assert rc_error._feature_only_trial(job, 1e-3) is None
