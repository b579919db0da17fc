"""The composer: a validated plan -> a pip-installable Nerfstudio plugin package.

The plugin's files form a dependency DAG (components -> field -> model -> config -> entry point,
README); they are rendered from Jinja2 templates in topological order, each Python file parsed
as soon as it exists and formatted with ruff, and the folder is published atomically.
"""

from __future__ import annotations

import ast
import json
import subprocess
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import jinja2
import networkx as nx
import yaml

from nerfify_ns import runfolder
from nerfify_ns.atomic import atomic_dir
from nerfify_ns.errors import NerfifyError
from nerfify_ns.grammar import Grammar, load_grammar, validate
from nerfify_ns.plan import Plan
from nerfify_ns.synthesis.context import Context, Names, build_context, component_source, py
from nerfify_ns.synthesis.repairs import reapply_repairs
from nerfify_ns.synthesis.resources import templates_dir


class CompositionError(NerfifyError):
    """A template produced code that does not parse (a bug in a template or snippet)."""


@dataclass
class PluginFile:
    """One file of the generated plugin: where it goes, its template and what it depends on."""

    path: str
    template: str
    depends_on: tuple = ()


@dataclass
class ComposedPlugin:
    out: Path
    method: str
    package: str
    files: list[str]
    plan: dict
    repairs: list[dict] = field(default_factory=list)
    """What became of each code repair recorded in the plan (``repairs``): applied, already present or
    does not apply."""


def plugin_files(ctx: dict) -> nx.DiGraph:
    """The plugin's files and their dependencies (an edge a -> b: b imports or describes a)."""
    pkg = ctx["package"]
    init = f"{pkg}/components/__init__.py"
    files = [PluginFile(init, "components_init.py.j2")] if ctx["components"] or ctx["custom_modules"] else []
    files += [PluginFile(f"{pkg}/components/{m}.py", f"component:{m}", (init,)) for m in ctx["components"]]
    files += [PluginFile(f"{pkg}/{m.replace('.', '/')}.py", f"source:{m}", (init,)) for m in ctx["custom_modules"]]
    component_files = tuple(f.path for f in files)
    field_files = (f"{pkg}/field.py",) if ctx["field_template"] else ()
    files += [PluginFile(f"{pkg}/field.py", ctx["field_template"], component_files)] if field_files else []
    sampler_files = (f"{pkg}/pixel_sampler.py",) if ctx.get("pixel_sampler") else ()
    files += [PluginFile(sampler_files[0], "pixel_sampler.py.j2", component_files)] if sampler_files else []
    files += [
        PluginFile(f"{pkg}/model.py", ctx["model_template"], (*field_files, *component_files)),
        PluginFile(f"{pkg}/config.py", "config.py.j2", (f"{pkg}/model.py", *sampler_files)),
        PluginFile(f"{pkg}/__init__.py", "__init__.py.j2", (f"{pkg}/config.py",)),
        PluginFile("pyproject.toml", "pyproject.toml.j2", (f"{pkg}/config.py",)),
        PluginFile(runfolder.PLAN, "plan"),
        PluginFile("README.md", "README.md.j2", (f"{pkg}/config.py", runfolder.PLAN)),
    ]
    graph = nx.DiGraph()
    for f in files:
        graph.add_node(f.path, file=f)
        for dep in f.depends_on:
            graph.add_edge(dep, f.path)
    return graph


def _environment() -> jinja2.Environment:
    env = jinja2.Environment(loader=jinja2.FileSystemLoader(str(templates_dir())), undefined=jinja2.StrictUndefined,
                             trim_blocks=True, lstrip_blocks=True, keep_trailing_newline=True)
    env.filters["tuple_literal"] = py
    return env


def _ruff(args: list[str], code: str, path: str) -> str:
    try:  # ruff's own lookup: the environment's scripts, the user's, or beside a ``pip install --target``
        from ruff.__main__ import find_ruff_bin

        ruff = find_ruff_bin()
    except (ImportError, FileNotFoundError):
        raise CompositionError("ruff (a dependency of nerfify-ns, which formats generated code) is not installed "
                               "where this Python finds it") from None
    result = subprocess.run([str(ruff), *args, "--stdin-filename", path, "-"],
                            input=code, capture_output=True, text=True, timeout=60)
    if result.returncode != 0:
        raise CompositionError(f"ruff failed on generated {path}: {(result.stderr or result.stdout).strip()[:300]}")
    return result.stdout


def _format_python(code: str, path: str) -> str:
    """Parse (a template bug is caught here), sort imports, drop unused ones, format."""
    try:
        ast.parse(code)
    except SyntaxError as exc:
        raise CompositionError(f"generated {path} does not parse (line {exc.lineno}: {exc.msg}); "
                               "this is a template bug, please report it") from None
    code = _ruff(["check", "--quiet", "--select", "I,F401", "--fix", "--exit-zero", "--line-length", "110"], code, path)
    return _ruff(["format", "--quiet", "--line-length", "110"], code, path)


def _render(env: jinja2.Environment, f: PluginFile, ctx: dict, plan: dict, sources: Mapping[str, str]) -> str:
    if f.template == "plan":
        return yaml.safe_dump(Plan.of(plan).to_dict(), sort_keys=False, width=110)
    if f.template.startswith("component:"):
        return component_source(f.template.split(":", 1)[1])
    if f.template.startswith("source:"):
        return _custom_source(f.template.split(":", 1)[1], sources, f.path)
    return env.get_template(f.template).render(**ctx)


def _custom_source(module: str, sources: Mapping[str, str], path: str) -> str:
    """The source of a custom component the plan names: given to the composer, written as it is (it is
    checked by the ladder like any code of the plugin); it must parse."""
    if module not in sources:
        raise CompositionError(f"the plan names the custom component module {module!r} but no source was given "
                               f"for it (pass its file, e.g. ns-nerfify compose PLAN --components DIR with "
                               f"{module.split('.')[-1]}.py in DIR)")
    text = sources[module]
    try:
        ast.parse(text)
    except SyntaxError as exc:
        raise CompositionError(f"the custom component {module} does not parse (line {exc.lineno}: {exc.msg})") from None
    return text if text.endswith("\n") else text + "\n"


def plugin_sources(plugin_dir: Path, plan: dict) -> dict[str, str]:
    """The sources of the custom components of an existing plugin (to recompose it from its plan)."""
    package = Names.of(plan["method"]).package
    modules = {v["module"] for _, v in _custom_entries(plan)}
    found = {}
    for module in modules:
        path = Path(plugin_dir) / package / (module.replace(".", "/") + ".py")
        if path.is_file():
            found[module] = path.read_text()
    return found


def _custom_entries(plan: dict) -> list[tuple]:
    derivation = validate(plan)
    return [(path, Plan.of(plan).get(path)) for path, term in derivation.used.items() if term == "custom"]


def sources_from_folder(folder: Path) -> dict[str, str]:
    """Custom component sources from a folder of ``<module>.py`` files (``components.<module>``)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise CompositionError(f"--components {folder} is not a folder of component files (<module>.py)")
    return {f"components.{p.stem}": p.read_text() for p in sorted(folder.glob("*.py")) if p.stem.isidentifier()}


def readme_rows(context: Context, ctx: dict) -> list[dict]:
    pkg = ctx["package"]
    rows = [{"file": f"{pkg}/{p.file}", "part": p.role, "path": p.path, "implementation": p.implementation,
             "evidence": (p.evidence or p.source).replace("|", "/")} for p in context.parts]
    for kw in ctx["config"]["model"]:
        rows.append({"file": f"{pkg}/config.py", "part": f"config `{kw.name}`", "path": kw.source.split(" ")[0],
                     "implementation": ctx["base"]["config_class"], "evidence": ""})
    return rows


def write_plugin(plan: dict, folder: Path, *, grammar: Grammar | None = None,
                 sources: Mapping[str, str] | None = None, one_shot: bool = False) -> ComposedPlugin:
    """Validate ``plan`` and render its plugin into the existing, empty ``folder``; ``sources`` holds the
    code of the plan's custom components (``components.<module>`` -> source). ``one_shot`` (the ablation
    ``one-shot``): every file rendered in one pass in declaration order, none parsed or formatted as it is
    written (a broken file is left for the ladder to find), instead of the DAG's topological order."""
    g = grammar or load_grammar()
    derivation = validate(plan, g)
    context = Context(names=Names.of(plan["method"]), plan=plan, derivation=derivation, grammar=g)
    ctx = build_context(context)
    ctx["readme"] = {"rows": readme_rows(context, ctx), "pruned": plan.get("pruned") or [],
                     "holes": plan.get("holes") or [], "notes": plan.get("notes") or []}
    graph = plugin_files(ctx)
    env = _environment()
    written: list[str] = []
    for name in (list(graph.nodes) if one_shot else nx.topological_sort(graph)):
        f: PluginFile = graph.nodes[name]["file"]
        text = _render(env, f, ctx, plan, sources or {})
        if name.endswith(".py") and not f.template.startswith("source:") and not one_shot:
            text = _format_python(text, name)
        target = Path(folder) / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text)
        written.append(name)
    repairs = reapply_repairs(plan, Path(folder))  # recorded ladder repairs, reported in README.md
    meta = {"method": ctx["method"], "package": ctx["package"],
            "config": f"{ctx['package']}.config:{ctx['config']['var']}", "files": written,
            "composition": "one-shot" if one_shot else "file-dag",
            **({"repairs": repairs} if repairs else {})}
    (Path(folder) / runfolder.PLUGIN_META).write_text(json.dumps(meta, indent=2))
    return ComposedPlugin(out=Path(folder).absolute(), method=ctx["method"], package=ctx["package"],
                          files=written, plan=plan, repairs=repairs)


def compose(plan: dict, out: Path, *, overwrite: bool = False, grammar: Grammar | None = None,
            record: bool = True, sources: Mapping[str, str] | None = None) -> ComposedPlugin:
    """Validate ``plan`` and write its plugin package to ``out`` (atomically). ``record`` is kept for callers
    and does nothing: there is no global "last generated" plugin (``ns-train nerfify-generated`` resolves
    $NERFIFY_GENERATED or the newest plugin under ./nerfify-out, :mod:`nerfify_ns.synthesis.plugin_lookup`)."""
    with atomic_dir(out, overwrite) as staging:
        result = write_plugin(plan, staging, grammar=grammar, sources=sources)
    result.out = Path(out).absolute()
    return result
