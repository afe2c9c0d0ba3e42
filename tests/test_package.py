"""The installed package: every module imports, each exactly once (one copy of every class), under one name."""

from __future__ import annotations

import importlib
import importlib.util
import pkgutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomllib

REPO = Path(__file__).resolve().parent.parent

# Folders of the checkout that are installed under the tetweave_codec namespace (pyproject's package-dir mapping):
# walk_packages does not find them through tetweave_codec.__path__ in an editable install, so they are walked too.
MAPPED = ("tetweave_codec.cli", "tetweave_codec.formats", "tetweave_codec.benchmarks", "tetweave_codec.web")


def _all_modules() -> list[str]:
    names = []
    for root in ("tetweave_codec", *MAPPED):
        package = importlib.import_module(root)
        names.append(root)
        for info in pkgutil.walk_packages(package.__path__, prefix=root + "."):
            if info.name.rsplit(".", 1)[-1] != "__main__":  # importing it would run the CLI
                names.append(info.name)
    return sorted(set(names))


def test_pyproject_lists_every_package():
    packages = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    found = [name for name in _all_modules() if hasattr(importlib.import_module(name), "__path__")]
    assert sorted(packages) == found


def test_every_module_imports_once_under_one_name():
    names = _all_modules()
    assert {"tetweave_codec.metrics.fidelity", "tetweave_codec.fit.loop", "tetweave_codec.formats.tw"} <= set(names)
    for name in names:
        importlib.import_module(name)
    by_file: dict[str, list[str]] = {}
    for mod_name, module in list(sys.modules.items()):
        path = getattr(module, "__file__", None)
        if path and Path(path).is_absolute() and Path(path).is_relative_to(REPO) and "tests" not in Path(path).parts:
            by_file.setdefault(str(Path(path).resolve()), []).append(mod_name)
    twice = {path: mods for path, mods in by_file.items() if len(mods) > 1}
    assert not twice, f"modules loaded under two names (two copies of every class in them): {twice}"
    # every module of the checkout that is loaded is loaded as part of tetweave_codec
    assert all(mods[0].startswith("tetweave_codec") for mods in by_file.values()), by_file


def test_no_nested_copy_of_the_package():
    assert importlib.util.find_spec("tetweave_codec.tetweave_codec") is None
    with pytest.raises(ModuleNotFoundError):
        importlib.import_module("tetweave_codec.tetweave_codec")


def test_the_container_class_is_the_one_the_decoder_uses():
    from tetweave_codec.decoder import decode
    from tetweave_codec.formats import tw

    points = np.random.default_rng(0).uniform(-1, 1, (300, 3))
    s = np.linalg.norm(points, axis=1) - 0.5
    f = tw.TetWeaveFile(
        points.astype(np.float16), s.astype(np.float16), np.zeros((300, 1), np.float16), 0, 1.0, np.zeros(3)
    )
    data = tw.pack(f)
    assert type(tw.unpack(data)) is tw.TetWeaveFile
    assert len(decode(data)[1]) > 0
    # the decoder's lazy import resolves to this very module object
    assert sys.modules["tetweave_codec.formats.tw"] is tw


def test_imports_work_outside_the_checkout(tmp_path):
    """An installed user has no repository root on sys.path: the mapped packages still import (and `formats` does
    not exist as a top-level name)."""
    code = (
        "import importlib.util, tetweave_codec.formats.tw, tetweave_codec.cli.main, tetweave_codec.metrics; "
        "assert importlib.util.find_spec('formats') is None and importlib.util.find_spec('cli') is None"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
