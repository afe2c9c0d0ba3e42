"""Which files a batch works on and where each result goes.

Inputs are files, directories (searched recursively for the given extensions) and ``@list.txt`` files (one path
per line; blank lines and lines starting with ``#`` are ignored; relative paths are relative to the list's
folder). Every input gets a path relative to its root: a directory's files relative to the directory, a list's
entries relative to the list's folder, files named on the command line relative to the working directory. The
outputs mirror these relative paths under the output directory (``DIR/a/b/mesh.tw``); inputs outside their root
(absolute paths elsewhere, ``..``) keep only their file name. Two inputs that would write the same output are a
usage error, found before any work.
"""

from __future__ import annotations

import os
import tempfile
from dataclasses import dataclass
from pathlib import Path, PurePosixPath

from tetweave_codec.errors import InputError

LIST_PREFIX = "@"  # `@list.txt`: a file that lists the inputs, one per line
LIST_COMMENT = "#"


@dataclass(frozen=True)
class Source:
    """One input file: `path` (as found, may not exist: it then fails in its own record) and `rel`, its path
    relative to its root, which the output mirrors."""

    path: Path
    rel: PurePosixPath


def _relative(path: Path, root: Path) -> PurePosixPath:
    """`path` relative to `root` when it lies below it, else just its name."""
    try:
        rel = Path(os.path.abspath(path)).relative_to(os.path.abspath(root))
    except ValueError:
        return PurePosixPath(path.name)
    return PurePosixPath(rel.as_posix()) if rel.parts else PurePosixPath(path.name)


def _search(directory: Path, extensions: tuple[str, ...]) -> list[Source]:
    """The files below `directory` with one of `extensions` (case-insensitive), sorted; hidden files and folders
    (our own temporary files among them) are left out."""
    found = []
    for root, dirs, files in os.walk(directory, followlinks=False):
        dirs[:] = sorted(d for d in dirs if not d.startswith("."))
        for name in sorted(files):
            if not name.startswith(".") and Path(name).suffix.lower() in extensions:
                path = Path(root) / name
                found.append(Source(path, _relative(path, directory)))
    return sorted(found, key=lambda source: source.rel.parts)


def _read_list(list_file: Path) -> list[Path]:
    """The paths named in an @list file, relative ones taken relative to the list's folder."""
    try:
        lines = list_file.read_text(encoding="utf-8").splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{list_file}: cannot read the list of inputs ({exc})") from None
    entries = [line.strip() for line in lines]
    paths = [Path(e) for e in entries if e and not e.startswith(LIST_COMMENT)]
    return [p if p.is_absolute() else list_file.parent / p for p in paths]


def collect_inputs(args: list[str] | tuple[str, ...], extensions: tuple[str, ...]) -> list[Source]:
    """Expand command-line inputs (files, directories, @lists) into input files, in the order given, each once.

    extensions: lower-case suffixes with the dot that a directory search keeps (files named explicitly are kept
    whatever their suffix: a wrong one fails in its own record). Raises InputError for an unreadable @list or
    when nothing is found.
    """
    sources: list[Source] = []
    for arg in args:
        text = str(arg)
        if text.startswith(LIST_PREFIX) and len(text) > 1:
            list_file = Path(text[1:])
            for path in _read_list(list_file):
                if path.is_dir():
                    sources += _search(path, extensions)
                else:
                    sources.append(Source(path, _relative(path, list_file.parent)))
        elif Path(text).is_dir():
            sources += _search(Path(text), extensions)
        else:
            sources.append(Source(Path(text), _relative(Path(text), Path.cwd())))
    unique: dict[str, Source] = {}
    for source in sources:
        unique.setdefault(os.path.realpath(source.path), source)
    if not unique:
        raise InputError(f"no input files found ({', '.join(e[1:] for e in extensions)}) in {' '.join(args)}")
    return list(unique.values())


def is_batch(args: list[str] | tuple[str, ...]) -> bool:
    """True unless the inputs are exactly one path that is not a directory or an @list."""
    return len(args) != 1 or str(args[0]).startswith(LIST_PREFIX) or Path(args[0]).is_dir()


def output_paths(sources: list[Source], out_dir: Path, suffix: str) -> list[Path]:
    """`out_dir / rel` with the suffix replaced, for every source; InputError when two would collide."""
    outputs: list[Path] = []
    seen: dict[str, Path] = {}
    for source in sources:
        out = out_dir / Path(*source.rel.parts).with_suffix(suffix)
        key = os.path.normcase(os.path.abspath(out))
        if key in seen:
            raise InputError(f"{seen[key]} and {source.path} would both be written to {out}; rename one of them")
        seen[key] = source.path
        outputs.append(out)
    return outputs


def check_writable_dir(directory: Path, *, create: bool = False) -> None:
    """InputError unless `directory` exists (or, with `create`, can be made: its parent exists) and a file can be
    created in it. Called before any work, so a bad output path costs nothing."""
    if create and not directory.exists() and directory.parent.is_dir():
        try:
            directory.mkdir()
        except OSError as exc:
            raise InputError(f"{directory}: cannot create the output directory ({exc.strerror})") from None
    if not directory.is_dir():
        what = "is not a directory" if directory.exists() else "does not exist"
        raise InputError(f"{directory}: the output directory {what}")
    try:  # os.access is not enough: it ignores read-only mounts and ACLs
        with tempfile.NamedTemporaryFile(dir=directory, prefix=".tetweave-check."):
            pass
    except OSError as exc:
        raise InputError(f"{directory}: cannot write to the output directory ({exc.strerror})") from None


def check_output_file(output: Path) -> None:
    """InputError unless `output` can be written: not a directory, in an existing, writable directory."""
    if output.is_dir():
        raise InputError(f"{output}: is a directory; give a file name")
    check_writable_dir(Path(os.path.abspath(output)).parent)
