"""Exception types. The CLI turns every TetweaveError into one line on stderr and exit code 2."""


class TetweaveError(Exception):
    """Base class of every error the tool reports to users as a one-line message."""


class InputError(TetweaveError):
    """A user-supplied input (mesh file, option value) cannot be used."""


class ContainerError(TetweaveError):
    """A `.tw` container is malformed, truncated, corrupted or of an unsupported version."""


class TopologyError(TetweaveError):
    """An internal consistency check failed: a tetrahedralization that is not a proper one (overlapping or
    non-conforming tets) reached marching tets, which would otherwise return a non-manifold mesh."""


def error_line(exc: BaseException) -> str:
    """The one-line message users see for `exc`: what the CLI prints after "tetweave: error: " and what a batch
    records for a failed file. TetweaveError: its message; OSError: reason and file; anything else is a bug of
    ours, named as an internal error."""
    if isinstance(exc, TetweaveError):
        text = str(exc)
    elif isinstance(exc, OSError):
        where = f": {exc.filename}" if exc.filename else ""
        text = f"{exc.strerror or exc}{where}"
    elif isinstance(exc, MemoryError):
        text = "out of memory; try fewer points, a smaller --size, or --device cpu"
    else:
        text = f"internal error ({type(exc).__name__}: {exc})"
    return " ".join(text.split())  # one line, whatever the message held
