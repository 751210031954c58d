"""Shared test fixtures: paths to the repo and to the third-party data beside it."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
THIRDPARTY = REPO.parent / "shared" / "thirdparty"


@pytest.fixture
def thirdparty() -> Path:
    if not THIRDPARTY.is_dir():
        pytest.skip(f"third-party data not found at {THIRDPARTY}")
    return THIRDPARTY
