"""tetweave: mesh compression by fitting a TetWeave representation.

Data flow: mesh -> targets -> fit -> container (encode), container -> Delaunay -> marching tets -> mesh (decode).
Submodules are imported lazily so that `import tetweave_codec` stays cheap for the CLI.
"""

from __future__ import annotations

import os as _os

__version__ = "0.1.0"

# In a source checkout, cli/ and formats/ sit at the repository's top level (design card) while installed they are
# tetweave_codec.cli and tetweave_codec.formats (see pyproject.toml). Adding the checkout's root to this package's
# search path makes the installed import names work from the checkout too, whichever copy Python finds first.
_root = _os.path.dirname(_os.path.dirname(_os.path.abspath(__file__)))
if _os.path.isfile(_os.path.join(_root, "pyproject.toml")) and _os.path.isdir(_os.path.join(_root, "formats")):
    __path__.append(_root)  # type: ignore[name-defined]  # noqa: F821

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
