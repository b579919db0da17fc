"""nerfify_ns.package_data: the one place that finds templates/, method_configs/ and grammar_spec.yaml."""

from __future__ import annotations

from pathlib import Path

import pytest

from nerfify_ns import package_data as data
from nerfify_ns.errors import NerfifyError
from nerfify_ns.synthesis import resources

ROOT = Path(__file__).resolve().parents[1]


def test_checkout_reads_the_top_level_data():
    assert data.templates_dir() == ROOT / "templates"
    assert data.method_configs_dir() == ROOT / "method_configs"
    assert data.grammar_spec_path() == ROOT / "grammar_spec.yaml"
    assert resources.templates_dir() == ROOT / "templates"
    assert resources.reference_plan_path("nerfacto") == ROOT / "method_configs" / "nerfacto.yaml"


def _fake_layout(tmp_path: Path, monkeypatch, *, installed: bool, checkout: bool) -> Path:
    """A package folder with an installed ``_data`` and/or a source tree around it."""
    root = tmp_path / "tree"
    package = root / "nerfify_ns"
    package.mkdir(parents=True)
    if installed:
        (package / "_data" / "templates").mkdir(parents=True)
    if checkout:
        (root / "pyproject.toml").write_text("[project]\n")
        (root / "templates").mkdir()
        (root / "grammar_spec.yaml").write_text("{}\n")
    monkeypatch.setattr(data, "INSTALLED_DATA_DIR", package / "_data")
    monkeypatch.setattr(data, "CHECKOUT_DIR", root)
    return root


def test_installed_data_comes_first(tmp_path, monkeypatch):
    root = _fake_layout(tmp_path, monkeypatch, installed=True, checkout=True)
    assert data.templates_dir() == root / "nerfify_ns" / "_data" / "templates"
    assert data.grammar_spec_path() == root / "grammar_spec.yaml"  # not in _data: the checkout's


def test_a_folder_without_pyproject_is_not_a_checkout(tmp_path, monkeypatch):
    root = _fake_layout(tmp_path, monkeypatch, installed=False, checkout=True)
    (root / "pyproject.toml").unlink()  # e.g. site-packages holding another project's templates/
    with pytest.raises(data.ProjectDataMissingError, match="'templates' not found") as info:
        data.templates_dir()
    assert isinstance(info.value, NerfifyError)


def test_missing_data_names_what_was_searched(tmp_path, monkeypatch):
    _fake_layout(tmp_path, monkeypatch, installed=True, checkout=False)
    with pytest.raises(data.ProjectDataMissingError, match="method_configs.*_data"):
        data.method_configs_dir()
