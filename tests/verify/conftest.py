"""Fixtures of the verification-ladder tests."""

from __future__ import annotations

import pytest
from verify_helpers import compose_reference


@pytest.fixture(scope="session")
def reference_plugins(tiny_scene, tmp_path_factory):
    """name -> pristine plugin folder (composed once per session; copy before changing it)."""
    from nerfify_ns.synthesis.resources import reference_plans

    root = tmp_path_factory.mktemp("reference_plugins")
    return {name: compose_reference(name, tiny_scene, root / name) for name in reference_plans()}
