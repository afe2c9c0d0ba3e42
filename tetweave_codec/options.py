"""The options of one encode, validated once: `EncodeOptions`, what `tetweave encode` builds from its command line,
what a batch manifest records and what `encoder.encode(vertices, faces, options=...)` runs.

`check_encode_arguments` holds every check that needs no mesh; `EncodeOptions` runs it when it is made (so a bad
combination fails in one line before any mesh is loaded) and `encoder.encode` runs it for its keyword arguments.
Imports neither torch nor the encoder: batch drivers and workers build options without them.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace

from tetweave_codec.errors import InputError

MAX_POINTS = 1 << 22
DEFAULT_QUANTIZATION_POINTS = 16384  # the quantization overrides' base when rate control picks the points
# Where a file's points come from: "fit" places them by optimization (fit.loop), "grid" takes the cells of a band
# around the input (fit.grid), "best" encodes both (rate control only) and keeps the better file: the lower error
# for --size, the smaller file for --max-error. Same container, same decoder.
LAYOUTS = ("fit", "grid", "best")
# What becomes of an open input's holes: "close" (the decoded surface spans them: always watertight) or "keep"
# (the file lists the faces that span them, formats/holes.py, and the decoder removes them: a 2-manifold with
# the input's boundary). Closed inputs decode closed either way.
HOLES = ("close", "keep")
SH_DEGREES = ("auto", "none", "0", "1", "2", "3")
# What the fit takes as the input's surface (fit/visible.py): "all" its faces (the encode before --surface),
# "visible" the faces offscreen renders see from outside, oriented towards the views, "auto" the visible surface
# where the input needs it (inconsistent orientation, hidden area), else all of it (the same bytes as "all").
SURFACES = ("auto", "visible", "all")
# Options added to EncodeOptions after batch manifests existed, with the value runs before them had ("auto" gives
# clean inputs the bytes of before).
LATER_OPTIONS = {"layout": "fit", "holes": "close", "keep_creases": None, "surface": "auto"}


def check_encode_arguments(
    *,
    points: int | None,
    sh_degree: int | None,
    container_version: int,
    size: int | None,
    max_error: float | None,
    layout: str,
    quantization_given: bool,
    holes: str,
    smoothing: int | None,
    subdivision: int | None,
    keep_creases: bool | None,
    surface: str = "auto",
) -> None:
    """InputError (one line) for any option or combination `encoder.encode` cannot run, whatever the mesh.

    sh_degree: -1..3 or None (the encoder's choice); quantization_given: a v2 quantization (or one of its
    overrides) was given."""
    from tetweave_codec.formats.common import MAX_SUBDIVISION
    from tetweave_codec.geometry.sh import check_degree
    from tetweave_codec.geometry.smoothing import MAX_STEPS as MAX_SMOOTHING_STEPS

    if size is None and max_error is None and points is not None and not 64 <= points <= MAX_POINTS:
        raise InputError(f"points must be between 64 and {MAX_POINTS}, got {points}")
    if sh_degree is not None:
        try:
            check_degree(sh_degree)
        except ValueError as exc:
            raise InputError(f"{exc} (-1 = none)") from None
    if container_version not in (1, 2):
        raise InputError(f"container version must be 1 or 2, got {container_version}")
    if (size is not None or max_error is not None) and container_version != 2:
        raise InputError("--size and --max-error need container version 2")
    if size is not None and max_error is not None:
        raise InputError("give either a size or a maximum error, not both")
    if layout not in LAYOUTS:
        raise InputError(f"layout must be one of {', '.join(LAYOUTS)}, got {layout!r}")
    if layout != "fit" and (container_version != 2 or quantization_given):
        raise InputError(f"the {layout} layout needs container version 2 and chooses its own quantization")
    if holes not in HOLES:
        raise InputError(f"holes must be one of {', '.join(HOLES)}, got {holes!r}")
    if surface not in SURFACES:
        raise InputError(f"surface must be one of {', '.join(SURFACES)}, got {surface!r}")
    if holes == "keep" and container_version != 2:
        raise InputError("keeping holes open needs container version 2")
    if layout == "best" and size is None and max_error is None:
        raise InputError("the best layout compares the two layouts' files at a --size or --max-error")
    if smoothing is not None and not 0 <= smoothing <= MAX_SMOOTHING_STEPS:
        raise InputError(f"smoothing must be 0-{MAX_SMOOTHING_STEPS} steps, got {smoothing}")
    if smoothing and container_version != 2:
        raise InputError("smoothing needs container version 2")
    if subdivision is not None and not 0 <= subdivision <= MAX_SUBDIVISION:
        raise InputError(f"subdivision must be 0-{MAX_SUBDIVISION} levels, got {subdivision}")
    if subdivision and container_version != 2:
        raise InputError("subdivision needs container version 2")
    if keep_creases and container_version != 2:
        raise InputError("keeping creases in the smoothing needs container version 2")


def check_step_overrides(s_step: float | None, c_step: float | None) -> None:
    """InputError (one line, before any fit) for an --s-step / --c-step a version-2 file cannot store: as float32,
    finite and in [MIN_STEP, MAX_S_STEP] / [MIN_STEP, MAX_C_STEP] (formats.quantize.step_problem, which pack_v2
    applies to the file after the fit)."""
    import numpy as np

    from tetweave_codec.formats.quantize import MAX_C_STEP, MAX_S_STEP, step_problem

    for flag, value, largest in (("--s-step", s_step, MAX_S_STEP), ("--c-step", c_step, MAX_C_STEP)):
        if value is None:
            continue
        with np.errstate(over="ignore"):
            stored = float(np.float32(float(value)))
        if step_problem(flag, stored, largest) is not None:
            bound = "at least 2^-126 as a float32" if 0 <= stored < 1 else f"at most {largest:g}"
            raise InputError(f"{flag} must be {bound} (the steps a .tw file can store), got {value:g}")


def sh_degree_value(text: str) -> int | None:
    """The encoder's `sh_degree` for the CLI's --sh-degree: "auto" -> None (the encoder's choice), "none" -> -1."""
    return {"auto": None, "none": -1}[text] if text in ("auto", "none") else int(text)


@dataclass(frozen=True)
class EncodeOptions:
    """`tetweave encode`'s options for one file, validated when made (InputError: `check_encode_arguments`, and the
    quantization overrides only with the fit layout). JSON-able: a batch manifest records `as_dict()`.

    sh_degree: "auto", "none" or "0".."3". size: target bytes; max_error: target Chamfer distance (rate control).
    points: the fit's grid points; None = the encoder's choice from the input (`encoder.default_points`).
    format_version: 1 or 2. position_bits (fractional ones: formats.quantize.fractional_grid) / s_step / c_step:
    v2 quantization overrides (None = the defaults for `points`; not with the grid layout, which has its own).
    smoothing, subdivision: the decoder's Taubin steps and Loop levels (None = the encoder's default).
    keep_creases: the smoothing keeps the surface's creases (None = the encoder's default). layout:
    "fit", "grid" or "best" (LAYOUTS). holes: "close" or "keep" (HOLES: an open input's holes spanned, or kept
    open). surface: "auto", "visible" or "all" (SURFACES: what the fit takes as the input's surface). quality: a
    `fit.config.QUALITY` preset; iters: its main+late iterations (None = the preset's, scaled
    with the points). device: "auto", "cpu" or "cuda". threads: torch CPU threads (0 = torch's default; applied by
    the CLI and the batch workers). measure: compute the Chamfer distance.
    """

    points: int | None = None
    sh_degree: str = "auto"
    layout: str = "fit"
    holes: str = "close"
    surface: str = "auto"
    quality: str = "default"
    iters: int | None = None
    size: int | None = None
    max_error: float | None = None
    format_version: int = 2
    position_bits: float | None = None
    s_step: float | None = None
    c_step: float | None = None
    smoothing: int | None = None
    subdivision: int | None = None
    keep_creases: bool | None = None
    device: str = "auto"
    seed: int = 0
    threads: int = 0
    measure: bool = True

    def __post_init__(self):
        self.validate()

    def validate(self) -> None:
        """InputError for options no encode can run (see the class docstring)."""
        if self.sh_degree not in SH_DEGREES:
            raise InputError(f"SH degree must be one of {', '.join(SH_DEGREES)}, got {self.sh_degree!r}")
        overrides = (self.position_bits, self.s_step, self.c_step)
        if self.layout != "fit" and any(x is not None for x in overrides):
            raise InputError(
                f"the {self.layout} layout chooses its own quantization: drop --position-bits, --s-step, --c-step"
            )
        check_step_overrides(self.s_step, self.c_step)
        rate_given = self.size is not None or self.max_error is not None
        if self.points is None and not rate_given and any(x is not None for x in overrides):
            # the default quantization follows the point count, which without --points is chosen from the input
            raise InputError("--position-bits, --s-step and --c-step need --points (or --size / --max-error)")
        check_encode_arguments(
            points=self.points,
            sh_degree=sh_degree_value(self.sh_degree),
            container_version=self.format_version,
            size=self.size,
            max_error=self.max_error,
            layout=self.layout,
            quantization_given=False,  # the overrides are checked above; the fit layout's default is none
            holes=self.holes,
            smoothing=self.smoothing,
            subdivision=self.subdivision,
            keep_creases=self.keep_creases,
            surface=self.surface,
        )

    def as_dict(self) -> dict:
        """The options as a batch manifest records them (`EncodeOptions(**d)` rebuilds them); options added after
        manifests existed are left out at the value every earlier run had (LATER_OPTIONS), so a re-run of a batch
        started before them still skips the files it finished."""
        d = asdict(self)
        for name, value in LATER_OPTIONS.items():
            if d[name] == value:
                del d[name]
        return d

    def encoder_kwargs(self, device) -> dict:
        """Keyword arguments of `tetweave_codec.encoder.encode` (device: the resolved torch.device): the one
        translation of these options, which `encode(..., options=...)` applies."""
        from tetweave_codec.formats.quantize import default_quantization

        overrides = (self.position_bits, self.s_step, self.c_step)
        if self.points is None and all(x is None for x in overrides):
            quant = None  # the encoder chooses the points from the input, then their default quantization
        else:  # (points None here only with --size / --max-error, whose rate control chooses its own quantization)
            quant = default_quantization(self.points or DEFAULT_QUANTIZATION_POINTS)
        if self.position_bits is not None:
            from tetweave_codec.formats.quantize import fractional_grid

            bits, grid_scale = fractional_grid(self.position_bits)
            quant = replace(quant, position_bits=bits, grid_scale=grid_scale)
        if self.s_step is not None:
            quant = replace(quant, s_step=self.s_step)
        if self.c_step is not None:
            quant = replace(quant, c_band_steps=(self.c_step,) * 4)
        return dict(
            points=self.points,
            sh_degree=sh_degree_value(self.sh_degree),
            quality=self.quality,
            iters=self.iters,
            device=device,
            seed=self.seed,
            container_version=int(self.format_version),
            quantization=quant if self.layout == "fit" else None,  # None with points None: no overrides (validate)
            layout=self.layout,
            holes=self.holes,
            size=self.size,
            max_error=self.max_error,
            measure=self.measure,
            smoothing=self.smoothing,
            subdivision=self.subdivision,
            keep_creases=self.keep_creases,
            surface=self.surface,
        )
