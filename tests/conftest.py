"""Fixtures shared by the whole suite."""

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` beside the checkout; skips the test when it is absent."""
    if not (SHARED_DATA / "ur10-ipa").is_dir():
        pytest.skip(f"real UR10 data not found at {SHARED_DATA} (../shared is absent)")
    return SHARED_DATA
