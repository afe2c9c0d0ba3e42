"""Shared fixtures. Tests generate their own small shapes; real meshes come from ../shared/meshes when present."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
SHARED_MESHES = REPO.parent / "shared" / "meshes"

# Fits are torch-heavy and the CI machine has two cores: keep torch to a fixed, small thread count so that runs are
# reproducible and never oversubscribe (set TETWEAVE_TEST_THREADS to change it).
os.environ.setdefault("TETWEAVE_TEST_THREADS", "2")


@pytest.fixture(autouse=True, scope="session")
def _torch_threads():
    import torch

    torch.set_num_threads(int(os.environ["TETWEAVE_TEST_THREADS"]))
    yield


@pytest.fixture
def shared_meshes() -> Path:
    if not SHARED_MESHES.is_dir():
        pytest.skip("../shared/meshes is not present")
    return SHARED_MESHES
