"""Typed exceptions raised by the procedural scene package."""

from __future__ import annotations

from collections.abc import Iterable

from nerfify_ns.errors import NerfifyError


class SceneError(NerfifyError):
    """Base class of every error raised by :mod:`nerfify_ns.scenes`."""


class UnknownSceneError(SceneError, KeyError):
    """A scene name that the catalog does not define."""

    def __init__(self, name: str, valid: Iterable[str]) -> None:
        self.name = name
        self.valid = sorted(valid)
        super().__init__(f"unknown scene {name!r}; valid scenes: {', '.join(self.valid)}")

    def __str__(self) -> str:  # KeyError would otherwise repr() the message
        return str(self.args[0])


class SceneExistsError(SceneError, FileExistsError):
    """The output folder exists and is not empty, and overwriting was not asked for."""


class SceneSpecError(SceneError, ValueError):
    """A scene specification (catalog entry or hand-written dict) is malformed."""


class SceneSettingsError(SceneError, ValueError):
    """A rendering setting out of its range (resolution, supersampling, view counts, seed)."""
