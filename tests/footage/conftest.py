"""Shared fixtures of the footage tests (helpers live in footage_helpers.py)."""

import pytest
from footage_helpers import texture_frames


@pytest.fixture(scope="session")
def frames40():
    return texture_frames(40)
