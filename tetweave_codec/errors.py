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
