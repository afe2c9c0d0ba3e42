"""tetweave: mesh compression by fitting a TetWeave representation.

Data flow: mesh -> prepared input -> fit -> container (encode), container -> Delaunay -> marching tets -> filter -> mesh
(decode).
Submodules are imported lazily so that `import tetweave_codec` stays cheap for the CLI.
"""

from __future__ import annotations

__version__ = "0.1.0"

__all__ = ["decode", "encode", "__version__"]


def __getattr__(name: str):
    # encode/decode pull in torch and scipy: load them on first use, not on `import tetweave_codec`.
    if name == "encode":
        from tetweave_codec.encoder import encode

        return encode
    if name == "decode":
        from tetweave_codec.decoder import decode

        return decode
    raise AttributeError(f"module 'tetweave_codec' has no attribute {name!r}")
