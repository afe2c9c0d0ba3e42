"""The command line shared by the maintained benchmark scripts: which meshes (--meshes, --only), --quality and
--threads. The development meshes lie beside the repository (../shared/meshes); the scripts default to them."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from tetweave_codec.bench.batch import find_meshes

REPO = Path(__file__).resolve().parent.parent
DEFAULT_MESHES = REPO.parent / "shared" / "meshes"


def select_meshes(path: str | Path, only: str = "") -> list[Path]:
    """`find_meshes(path)`, kept to the comma-separated file stems of `only` when given."""
    paths = find_meshes(path)
    if only:
        keep = set(only.split(","))
        paths = [p for p in paths if p.stem in keep]
    return paths


def script_parser(description: str):
    """The command line shared by the benchmark scripts: --meshes, --only, --quality, --threads."""
    import argparse

    from tetweave_codec.fit.config import QUALITY

    ap = argparse.ArgumentParser(description=description, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--meshes", type=Path, default=DEFAULT_MESHES)
    ap.add_argument("--only", default="", help="comma-separated mesh stems to run (default: all)")
    ap.add_argument("--quality", default="default", choices=list(QUALITY))
    ap.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    return ap


def script_meshes(args) -> list[Path]:
    """Apply --threads and return the meshes of --meshes / --only (see `script_parser`)."""
    if args.threads:
        import torch

        torch.set_num_threads(args.threads)
    return select_meshes(args.meshes, args.only)


def commit_tree(commit: str, where: Path) -> Path:
    """`commit`'s source unpacked into where/tree (`git archive`), its C extensions built there (`setup.py build_ext
    --inplace`) and `cli`, `formats` and `benchmarks` linked into its package (what the editable install's
    package-dir mapping does): a subprocess with this tree first on PYTHONPATH runs that commit's code."""
    tree = where / "tree"
    tree.mkdir()
    archive = subprocess.run(["git", "-C", str(REPO), "archive", commit], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    for name in ("cli", "formats", "benchmarks"):
        (tree / "tetweave_codec" / name).symlink_to(Path("..") / name)
    subprocess.run([sys.executable, "setup.py", "build_ext", "--inplace"], cwd=tree, check=True, capture_output=True)
    return tree
