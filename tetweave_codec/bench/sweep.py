"""The adaptive classical sweep of `tetweave bench`: only the classical settings that decide the verdict.

The verdict (report.py) reads each classical family's size at the Chamfer distance e of every tetweave file off the
family's Pareto front (`metrics.rate_distortion.bytes_at`: log-log interpolation between the two front points
around e). On a family's grid of settings (one curve per Draco bit depth, ordered by file size: the decimation's
kept fraction, or Draco's bits), those two points are

- L, the smallest file whose error is at most e: on each curve the first setting that reaches e (the Chamfer
  distance falls and the bytes grow along a curve), found by a search on the curve's index (galloping from where
  the previous curve or target stopped, then interpolation in log(error) against the index, with bisection when
  that stalls); L is the smallest of these over the family's curves;
- R, the most accurate file smaller than L: on each curve the largest setting with fewer bytes than L. Usually the
  setting just before the bracket on some curve; a curve whose bracket setting is still larger than L is searched
  further down by bytes alone (encodes, no metric), and only when its bracket setting is more accurate than the
  best R so far (a setting further down cannot be more accurate than it).

With the Chamfer distance and the bytes monotone along every curve, L and R are the very points the full sweep's
front has around e, so the matched size is the full sweep's. Measured settings are kept as rows; the search
measures the Chamfer distance alone (`rows.reference_chamfer`, the same value as the full metrics); L and R of the
family smallest at each target get every metric (the verdict's normal consistency comparison, the tables). The
decimations are shared by the bit depths (`baselines.DecimationCache`) and never depend on the search's order.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from tetweave_codec.bench.methods import Method
from tetweave_codec.bench.rows import MeshResult, ProgressFn, encode_method, measure_method, say_row
from tetweave_codec.metrics.common import MetricOptions
from tetweave_codec.metrics.fidelity import Reference
from tetweave_codec.metrics.rate_distortion import bytes_at, pareto_front


@dataclass
class Setting:
    """One classical setting of the current mesh: its row (size columns once encoded, Chamfer once measured),
    the encoded bytes and the decoded mesh (kept for the pictures)."""

    method: Method
    row: dict | None = None
    data: bytes | None = None
    decoded: tuple[np.ndarray, np.ndarray] | None = None
    measured: bool = False  # Chamfer distance measured (or failed)
    complete: bool = False  # every metric measured

    @property
    def size(self) -> float:
        """Bytes; +inf for a failed encode (never the smallest file)."""
        return math.inf if self.data is None else float(len(self.data))

    @property
    def error(self) -> float:
        """Chamfer distance; +inf for a failure (never reaches a target)."""
        if self.row is None or self.row.get("error") or self.row.get("chamfer") in ("", None):
            return math.inf
        return float(self.row["chamfer"])


@dataclass
class Curve:
    """The settings of one family at one Draco bit depth (or the Draco family's bit depths), smallest file first."""

    family: str
    settings: list[Setting]
    slope: float | None = None  # expected fall of log(error) per setting, for the search's first steps
    start: int = field(default=-1)  # where the last search ended (-1: none yet)


def classical_curves(methods: Sequence[Method]) -> list[Curve]:
    """The classical methods grouped by rate-distortion curve (`Method.curve`), each ordered by file size: the kept
    fraction, then the bit depth (both grow the file)."""
    curves: dict[str, list[Method]] = {}
    for m in methods:
        curves.setdefault(m.curve, []).append(m)

    def order(m: Method) -> tuple[float, int]:
        p = m.params()
        return float(p.get("keep_fraction", 1.0)), int(p.get("quantization_bits", 0))

    out = []
    for ms in curves.values():
        ms = sorted(ms, key=order)
        keys = np.array([order(m) for m in ms], dtype=np.float64)
        slope = None
        if len(ms) > 1:
            # Chamfer distance ~ 1 / kept fraction (a quadric decimation's error ~ edge length squared), and halved
            # by each Draco bit (the quantization step)
            steps = np.log(keys[-1, 0] / keys[0, 0]) + np.log(2.0) * (keys[-1, 1] - keys[0, 1])
            slope = float(steps / (len(ms) - 1)) or None
        out.append(Curve(ms[0].family, [Setting(m) for m in ms], slope))
    return out


class Sweep:
    """Encodes and measures the classical settings of one mesh on demand, each at most once."""

    def __init__(self, result: MeshResult, reference: Reference, options: MetricOptions, say: ProgressFn) -> None:
        self.result, self.reference, self.options, self.say = result, reference, options, say
        self.measured = 0

    def encode(self, s: Setting) -> float:
        """The setting's bytes (+inf on failure), encoding it if needed."""
        if s.row is None:
            s.row, s.data = encode_method(self.result.name, s.method, self.result.vertices, self.result.faces)
        return s.size

    def error(self, s: Setting, complete: bool = False) -> float:
        """The setting's Chamfer distance (+inf on failure); every metric with `complete`."""
        self.encode(s)
        if s.data is None or (s.measured and (s.complete or not complete)):
            s.measured = True
            return s.error
        if complete:  # the full metrics overwrite the Chamfer-only row (same Chamfer value)
            for key in ("decode_s", "metrics_s", "chamfer"):
                s.row[key] = ""
        s.decoded = measure_method(s.row, s.method, s.data, self.reference, self.options, chamfer_only=not complete)
        s.measured, s.complete = True, complete or bool(s.row.get("error"))
        self.measured += 1
        say_row(self.say, self.result.name, f"{s.method.name}{'' if complete else ' (Chamfer only)'}", s.row)
        return s.error


def bracket(
    error_at: Callable[[int], float], n: int, target: float, start: int, slope: float | None = None
) -> tuple[int, int]:
    """(lo, hi = lo + 1) on a curve of n settings whose error falls with the index: error(lo) > target >=
    error(hi), lo = -1 when the first setting already reaches the target, hi = n when none does. Gallops from
    `start` (steps 1, 2, 4, ..., or the step that `slope`, the expected fall of log(error) per index, predicts when
    that is longer) until the target is bracketed, then interpolates log(error) linearly in the index (bisecting
    whenever an interpolation step did not halve the interval)."""
    lo, hi = -1, n
    known: dict[int, float] = {}
    i = min(max(start, 0), n - 1)
    step, interpolate = 1, True
    while hi - lo > 1:
        known[i] = error_at(i)
        width = hi - lo
        if known[i] <= target:
            hi = i
        else:
            lo = i
        if hi - lo <= 1:
            break
        jump = step
        if slope and 0 < known[i] < math.inf:
            jump = max(step, round(abs(math.log(known[i] / target)) / slope))
        if lo < 0:  # nothing above the target seen yet: gallop towards smaller files
            i, step = max(0, hi - jump), 2 * step
        elif hi >= n:  # nothing at or below the target seen yet: gallop towards larger files
            i, step = min(n - 1, lo + jump), 2 * step
        else:
            guess = (lo + hi) // 2
            e_lo, e_hi = known[lo], known[hi]
            if interpolate and math.isfinite(e_lo) and 0 < e_hi < e_lo:
                t = (math.log(e_lo) - math.log(target)) / (math.log(e_lo) - math.log(e_hi))
                guess = lo + round(t * (hi - lo))
            i = min(max(guess, lo + 1), hi - 1)
            interpolate = 2 * (hi - lo) <= width  # the last step halved the interval: keep interpolating
    return lo, hi


def _search_family(sweep: Sweep, curves: list[Curve], target: float) -> tuple[Setting | None, Setting | None]:
    """Measure the settings that bracket `target` on the family's front: (L, R) of the module docstring, None
    where the family has none."""
    brackets = []
    previous = -1
    for curve in curves:
        n = len(curve.settings)
        start = curve.start if curve.start >= 0 else previous if previous >= 0 else n // 2
        lo, hi = bracket(lambda i, c=curve: sweep.error(c.settings[i]), n, target, start, curve.slope)
        curve.start = previous = min(hi, n - 1)
        brackets.append((curve, lo, hi))
    reaching = [(sweep.encode(c.settings[hi]), c.settings[hi]) for c, _, hi in brackets if hi < len(c.settings)]
    if not reaching:
        return None, None  # no setting of the family reaches the target: its front ends above it
    size_l, best_l = min(reaching, key=lambda x: x[0])
    best_r: Setting | None = None
    for curve, lo, _ in sorted(brackets, key=lambda b: b[0].settings[b[1]].error if b[1] >= 0 else math.inf):
        if lo < 0 or (best_r is not None and curve.settings[lo].error >= best_r.error):
            continue  # the curve's settings below the target are all less accurate than R already is
        k = _last_smaller(lambda i, c=curve: sweep.encode(c.settings[i]), lo, size_l)
        if k >= 0 and sweep.error(curve.settings[k]) < (best_r.error if best_r else math.inf):
            best_r = curve.settings[k]
    return best_l, best_r


def _last_smaller(size_at: Callable[[int], float], top: int, size: float) -> int:
    """The largest index <= top whose size is below `size` (sizes grow with the index), -1 if none: galloping
    down from top, then bisection."""
    if size_at(top) < size:
        return top
    hi, step = top, 1  # size_at(hi) >= size
    lo = -1
    while True:
        i = max(0, hi - step)
        if size_at(i) < size:
            lo = i
            break
        hi = i
        if i == 0:
            return -1
        step *= 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        if size_at(mid) < size:
            lo = mid
        else:
            hi = mid
    return lo


def adaptive_sweep(
    result: MeshResult,
    methods: Sequence[Method],
    targets: Sequence[float],
    reference: Reference,
    options: MetricOptions,
    say: ProgressFn,
) -> None:
    """The classical `methods` of result's mesh, measured only where they bracket the Chamfer distances `targets`
    (the tetweave files'); every setting when there is no target. Rows (in `methods`' order) and decoded meshes go
    into result."""
    t_wall, t_cpu = time.perf_counter(), time.process_time()
    curves = classical_curves(methods)
    sweep = Sweep(result, reference, options, say)
    targets = sorted({float(t) for t in targets if t > 0 and math.isfinite(t)})
    brackets: list[dict[str, tuple[Setting | None, Setting | None]]] = [{} for _ in targets]  # family -> (L, R)
    families: dict[str, list[Curve]] = {}
    for curve in curves:
        families.setdefault(curve.family, []).append(curve)
    for family_curves in families.values():
        # the most accurate bit depth first: its bracket is the best start for the others
        family_curves.sort(key=lambda c: -int(c.settings[0].method.params().get("quantization_bits", 0)))
        for k, target in enumerate(targets):
            brackets[k][family_curves[0].family] = _search_family(sweep, family_curves, target)
    for target, found in zip(targets, brackets, strict=True):
        # every metric for the two settings that decide the verdict at this target: those of the smallest family
        sizes = {}
        for family, (left, right) in found.items():
            front = pareto_front([(s.error, s.size) for s in (left, right) if s is not None])
            sizes[family] = bytes_at(front, target)
        decided = [(b, f) for f, b in sizes.items() if b is not None]
        if decided:
            for s in found[min(decided)[1]]:
                if s is not None:
                    sweep.error(s, complete=True)
    if not targets:
        for curve in curves:
            for s in curve.settings:
                sweep.error(s, complete=True)
    by_method = {id(s.method): s for c in curves for s in c.settings}
    for m in methods:
        s = by_method[id(m)]
        if s.measured:
            result.rows.append(s.row)
            if s.decoded is not None:
                result.decoded[m.name] = s.decoded
    say(
        f"{result.name}: adaptive classical sweep: {sweep.measured} measurement(s) of {len(methods)} settings, "
        f"{time.process_time() - t_cpu:.1f}s CPU, {time.perf_counter() - t_wall:.1f}s wall"
    )
