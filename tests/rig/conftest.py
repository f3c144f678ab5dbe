"""Fixtures of the rig tests."""

from __future__ import annotations

import pytest

from prt_torch.rig.builtin import make_character
from prt_torch.rig.character import Character


@pytest.fixture(scope="session")
def humanoid() -> Character:
    """The built-in humanoid at density 0.25 (~3k vertices); tests must not modify it."""
    return make_character(0.25)
