"""Build of the optional C extensions (the rest of the metadata is in pyproject.toml).

* `tetweave_codec.formats._native` (formats/_native.c, a binding over the decoder core's decoder/predict.c): the s
  prediction's decoder loops; formats/predict.py is the reference.
* `tetweave_codec.geometry._mt_native` (tetweave_codec/geometry/_mt_native.c): the integer topology of marching
  tets; geometry/marching_tets.py is the reference.
* `tetweave_codec.geometry._intersect_native` (tetweave_codec/geometry/_intersect_native.c): the self-intersection
  test of the decoder's smoothing check, on pthreads when the caller asks for threads; geometry/intersections.py is
  the reference.
* `tetweave_codec.geometry._filter_native` (tetweave_codec/geometry/_filter_native.c): the decoder's Taubin steps,
  Loop levels and crease test; geometry/smoothing.py and geometry/subdivision.py are the reference.
* `tetweave_codec.geometry._delaunay_native` (tetweave_codec/geometry/_delaunay_native.c): the exact Delaunay
  tetrahedralization of integer points under a fixed symbolic perturbation (the "exact" backend of
  geometry/delaunay.py, specified in its docstring). REQUIRED (`optional=False`): it has no Python fallback.
* `tetweave_codec._decoder_native` (tetweave_codec/_decoder_native.c, the binding of the whole decoder core in
  decoder/: file bytes in, mesh out; decoder/tetweave_decoder.h): what `decoder.decode` runs on the files of this
  version. REQUIRED: tetweave_codec/decoder.py keeps the Python pipeline as the reference and for older files.
* `tetweave_codec._text_native` (tetweave_codec/_text_native.c): the rows of the OBJ and OFF writers; meshio.py is
  the reference.

Each Python module falls back to its numpy/Python code when its extension is absent, with identical output.
`optional=True`: a machine without a C compiler still installs. The flags keep the binary64 results identical to
the reference's: no fused multiply-add contraction, no -ffast-math.
"""

import sys
from pathlib import Path

from setuptools import Extension, setup

FLAGS = [] if sys.platform == "win32" else ["-O2", "-ffp-contract=off", "-fno-fast-math"]
# _intersect_native.c runs its crossing check on pthreads when asked for threads (without pthreads, on Windows, it
# runs them on the calling thread: same flags)
THREAD_FLAGS = [] if sys.platform == "win32" else ["-pthread"]

# The decoder core (decoder/, C99, no Python.h): every source; tetweave_codec/_decoder_native.c is its binding.
CORE_SOURCES = sorted(str(p.as_posix()) for p in Path("decoder").glob("*.c"))

setup(
    ext_modules=[
        Extension(
            "tetweave_codec.formats._native",
            ["formats/_native.c", "decoder/predict.c", "decoder/common.c"],
            include_dirs=["decoder"],
            depends=["decoder/internal.h", "decoder/tetweave_decoder.h"],
            extra_compile_args=FLAGS,
            optional=True,
        ),
        Extension(
            "tetweave_codec.geometry._mt_native",
            ["tetweave_codec/geometry/_mt_native.c", "decoder/marching.c", "decoder/common.c"],
            include_dirs=["decoder"],
            depends=["decoder/internal.h", "decoder/tetweave_decoder.h", "decoder/radix.h"],
            extra_compile_args=FLAGS,
            optional=True,
        ),
        Extension(
            "tetweave_codec.geometry._intersect_native",
            ["tetweave_codec/geometry/_intersect_native.c", "decoder/intersect.c"],
            include_dirs=["decoder"],
            depends=["decoder/internal.h", "decoder/tetweave_decoder.h"],
            extra_compile_args=FLAGS + THREAD_FLAGS,
            extra_link_args=THREAD_FLAGS,
            optional=True,
        ),
        Extension(
            "tetweave_codec.geometry._filter_native",
            [
                "tetweave_codec/geometry/_filter_native.c",
                "decoder/filter.c",
                "decoder/loop.c",
                "decoder/intersect.c",
                "decoder/common.c",
            ],
            include_dirs=["decoder"],
            depends=["decoder/internal.h", "decoder/tetweave_decoder.h"],
            extra_compile_args=FLAGS + THREAD_FLAGS,
            extra_link_args=THREAD_FLAGS,
            optional=True,
        ),
        Extension(
            "tetweave_codec.geometry._delaunay_native",
            ["tetweave_codec/geometry/_delaunay_native.c", "decoder/delaunay.c", "decoder/common.c"],
            include_dirs=["decoder"],
            depends=["decoder/internal.h", "decoder/tetweave_decoder.h", "decoder/radix.h"],
            extra_compile_args=FLAGS,
            optional=False,
        ),
        Extension(
            "tetweave_codec._decoder_native",
            ["tetweave_codec/_decoder_native.c", *CORE_SOURCES],
            include_dirs=["decoder"],
            depends=["decoder/internal.h", "decoder/tetweave_decoder.h", "decoder/radix.h"],
            extra_compile_args=FLAGS + THREAD_FLAGS,
            extra_link_args=THREAD_FLAGS,
            optional=False,
        ),
        Extension(
            "tetweave_codec._text_native", ["tetweave_codec/_text_native.c"], extra_compile_args=FLAGS, optional=True
        ),
    ]
)
