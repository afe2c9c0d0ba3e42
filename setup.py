"""Build of the optional C extension `tetweave_codec.formats._native` (the rest of the metadata is in pyproject.toml).

The extension is the compiled fast path of the s prediction's decoder loops (formats/_native.c); formats/predict.py
is the reference and falls back to numpy/Python when it is absent, with identical output. `optional=True`: a
machine without a C compiler still installs. The flags keep the binary64 results identical to the reference's:
no fused multiply-add contraction, no -ffast-math.
"""

import sys

from setuptools import Extension, setup

FLAGS = [] if sys.platform == "win32" else ["-O2", "-ffp-contract=off", "-fno-fast-math"]

setup(
    ext_modules=[
        Extension("tetweave_codec.formats._native", ["formats/_native.c"], extra_compile_args=FLAGS, optional=True)
    ]
)
