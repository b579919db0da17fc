"""The wheel installs standalone: ``pip wheel`` of the repository, installed (not editable) into a
fresh virtual environment, composes a plugin from a reference plan and verifies it from a folder
outside the repository.

The heavy dependencies (torch, Nerfstudio, ...) are not reinstalled: the fresh environment borrows
``.venv``'s installed distributions (symlinks in its site-packages, their console scripts rewritten
for the fresh interpreter, as pip would write them), all but ``.venv``'s own editable nerfify-ns.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import sysconfig
import zipfile
from importlib import metadata
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PROJECT_DATA = ("templates", "method_configs", "grammar_spec.yaml")
DATA_IN_WHEEL = "nerfify_ns/_data"

pytestmark = pytest.mark.slow


def _run(cmd: list[str], *, cwd: Path, env: dict[str, str], timeout: float = 300) -> str:
    """Run ``cmd``; fail the test with its output unless it exits 0."""
    result = subprocess.run([str(c) for c in cmd], cwd=cwd, env=env, capture_output=True, text=True,
                            timeout=timeout)
    output = f"{result.stdout[-3000:]}\n{result.stderr[-3000:]}"
    assert result.returncode == 0, f"{cmd[:3]} exited {result.returncode}:\n{output}"
    return result.stdout


def _clean_env(tmp: Path) -> dict[str, str]:
    """The environment of a user outside the repository: no PYTHONPATH, no active venv, own cache."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("PYTHON") and k != "VIRTUAL_ENV"}
    env["NERFIFY_CACHE"] = str(tmp / "cache")
    env["PYTHONDONTWRITEBYTECODE"] = "1"  # never write into .venv's borrowed packages
    return env


def _git_files(*paths: str) -> list[str]:
    """Files under ``paths`` that git tracks or would track (what .gitignore does not exclude)."""
    out = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "--", *paths],
                         cwd=ROOT, capture_output=True, text=True, check=True).stdout
    return [p for p in out.splitlines() if (ROOT / p).is_file()]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel of this checkout, built offline with the dev extra's hatchling."""
    out = tmp_path_factory.mktemp("wheel")
    _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "--quiet",
          "-w", out, ROOT], cwd=out, env=_clean_env(out))
    (built,) = out.glob("nerfify_ns-*.whl")
    return built


def test_package_has_no_symlinks():
    links = [str(p.relative_to(ROOT)) for p in (ROOT / "nerfify_ns").rglob("*") if p.is_symlink()]
    assert not links, f"symlinks inside the package (a wheel would not carry their targets): {links}"


def test_wheel_carries_project_data_and_every_package_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    data_files = _git_files(*PROJECT_DATA)
    assert any(f.endswith(".j2") for f in data_files) and "grammar_spec.yaml" in data_files
    missing = [f for f in data_files if f"{DATA_IN_WHEEL}/{f}" not in names]
    assert not missing, f"project data missing from the wheel: {missing}"
    package_files = _git_files("nerfify_ns")
    assert any(not f.endswith(".py") for f in package_files)
    missing = [f for f in package_files if f not in names]
    assert not missing, f"package files missing from the wheel: {missing}"
    assert not [n for n in names if "__pycache__" in n or n.endswith(".pyc")]
    assert not [n for n in names if n.split("/")[0] in PROJECT_DATA], "project data outside the package"


def _own_entries(dist: metadata.Distribution) -> set[str]:
    """Top-level site-packages entries that belong to ``dist`` (its RECORD)."""
    return {f.parts[0] for f in dist.files or [] if f.parts and f.parts[0] != ".."}


def _borrow_dependencies(site: Path, venv_bin: Path, python: Path) -> None:
    """Make ``.venv``'s distributions, all but nerfify-ns, visible in the fresh environment."""
    source = Path(sysconfig.get_path("purelib"))
    dists = list(metadata.distributions(path=[str(source)]))
    ours = [d for d in dists if re.sub(r"[-_.]+", "-", d.metadata["Name"]).lower() == "nerfify-ns"]
    assert ours, "the test expects .venv to hold nerfify-ns (scripts/setup.sh)"
    skip = {"__pycache__"}.union(*(_own_entries(d) for d in ours))
    for entry in source.iterdir():
        if entry.name not in skip and not (site / entry.name).exists():
            (site / entry.name).symlink_to(entry)
    for dist in dists:
        if dist in ours:
            continue
        for f in dist.files or []:
            if len(f.parts) > 1 and f.parts[0] == ".." and f.parts[-2] == "bin":
                _borrow_script(Path(dist.locate_file(f)), venv_bin / f.name, python)


def _borrow_script(src: Path, dst: Path, python: Path) -> None:
    """A dependency's script in the fresh environment: a Python launcher gets the fresh interpreter in
    its shebang (as pip writes it); anything else (ruff's binary) is linked."""
    if not src.is_file() or dst.exists():
        return
    head, _, rest = src.read_bytes().partition(b"\n")
    if head.startswith(b"#!") and b"python" in head:
        dst.write_bytes(b"#!" + str(python).encode() + b"\n" + rest)
        dst.chmod(0o755)
    else:
        dst.symlink_to(src)


@pytest.fixture(scope="module")
def installed(wheel, tmp_path_factory) -> Path:
    """A fresh virtual environment with the wheel installed, not editable; returns its folder."""
    venv = tmp_path_factory.mktemp("venv") / "env"
    env = _clean_env(venv.parent)
    _run([sys.executable, "-m", "venv", "--without-pip", venv], cwd=venv.parent, env=env)
    python = venv / "bin" / "python"
    site = Path(_run([python, "-I", "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                     cwd=venv.parent, env=env).strip())
    _borrow_dependencies(site, venv / "bin", python)
    _run([python, "-I", "-m", "pip", "install", "--no-deps", "--no-index", "--quiet", wheel],
         cwd=venv.parent, env=env)
    assert (site / "nerfify_ns").is_dir() and not (site / "nerfify_ns").is_symlink()
    return venv


LOCATE = """
import json, sys, nerfify_ns
from importlib.metadata import entry_points
from nerfify_ns import package_data as data
from nerfify_ns.grammar.spec import load_grammar
from nerfify_ns.synthesis.resources import reference_plans
(ep,) = [e for e in entry_points(group="nerfstudio.method_configs") if e.name == "nerfify-generated"]
print(json.dumps({"package": nerfify_ns.__file__, "templates": str(data.templates_dir()),
                  "method_configs": str(data.method_configs_dir()), "grammar": str(data.grammar_spec_path()),
                  "entry_point": ep.load() and sys.modules[ep.module].__file__, "plans": reference_plans(),
                  "terminals": len(load_grammar().terminals)}))
"""


def test_installed_wheel_finds_its_own_data(installed, tmp_path):
    python = installed / "bin" / "python"
    found = json.loads(_run([python, "-I", "-c", LOCATE], cwd=tmp_path, env=_clean_env(tmp_path)))
    venv = installed.resolve()
    for key in ("package", "templates", "method_configs", "grammar", "entry_point"):
        path = Path(found[key]).resolve()
        assert venv in path.parents, f"{key} is read from {path}, not from the installed wheel"
        assert ROOT not in path.parents
    assert Path(found["templates"]).parent.name == "_data"
    assert "vanilla-nerf" in found["plans"] and found["terminals"] > 10


def test_installed_wheel_composes_and_verifies_a_plugin(installed, tmp_path):
    """The installed console script composes vanilla-nerf and passes the static and contract rungs."""
    env = _clean_env(tmp_path)
    cli = installed / "bin" / "ns-nerfify"
    plugin = tmp_path / "plugin"
    _run([cli, "compose", "--method", "vanilla-nerf", "--until", "plugin", "--out", plugin], cwd=tmp_path, env=env)
    assert (plugin / "pyproject.toml").is_file() and (plugin / "plan.yaml").is_file()
    assert list(plugin.glob("*/model.py")) and list(plugin.glob("*/field.py"))
    verify_out = tmp_path / "verify"
    _run([cli, "verify", plugin, "--rungs", "static", "contract", "--no-propose", "--out", verify_out],
         cwd=tmp_path, env=env)
    report = json.loads((verify_out / "verify.json").read_text())
    statuses = {r["name"]: r["status"] for r in report["rungs"]}
    assert statuses == {"static": "pass", "contract": "pass"}, report
