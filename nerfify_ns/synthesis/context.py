"""From a validated plan to the values the plugin templates render.

Terminal code comes from the terminal registry (``nerfify_ns/registry``: each terminal's ``Code``) and
base models from their one definition (``nerfify_ns/registry/bases.yaml``);
base-model config values come from each terminal's ``config`` mapping in ``grammar_spec.yaml``.
Every value carries the plan entry it comes from, so the generated code can say so.
"""

from __future__ import annotations

import dataclasses
import importlib
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from importlib import resources
from typing import Any

from nerfify_ns.errors import NerfifyError
from nerfify_ns.grammar import Derivation, Grammar
from nerfify_ns.grammar.spec import CUSTOM
from nerfify_ns.knowledge import KnowledgeBase
from nerfify_ns.knowledge import card as load_card
from nerfify_ns.plan import Plan, package_name
from nerfify_ns.registry import default_registry
from nerfify_ns.registry.bases import plugin_facts as bases
from nerfify_ns.registry.snippets import py, render
from nerfify_ns.registry.terminals.heads import ACTIVATIONS, backbone_skips
from nerfify_ns.registry.terminals.losses import plane_owner
from nerfify_ns.registry.terminals.sampling import proposal_resolutions
from nerfify_ns.synthesis.proxy import SIZES, proxy_spec


def one(mapping: dict) -> tuple[str, Any]:
    """The single (alternative, value) of a choice."""
    (key, value), = mapping.items()
    return key, value


def render_snippet(text: str, params: dict, package: str) -> str:
    return render(text, params, package)


def snippet(terminal: str) -> dict | None:
    """What ``terminal`` renders (imports, ctor, expr, component, traits), None when it renders nothing
    of its own (the base model's config realises it)."""
    code = default_registry()[terminal].code
    data = {"imports": list(code.imports), "ctor": code.ctor, "expr": code.expr, "component": code.component,
            **code.traits}
    return data if (code.ctor or code.expr or code.imports or code.traits) else None


def dataparser_snippet(name: str) -> dict:
    """The import and constructor of the Nerfstudio dataparser config ``name``."""
    module, cls = default_registry()["datamanager"].code.traits["dataparsers"][name]
    return {"imports": [f"from {module} import {cls}"], "ctor": f"{cls}()"}


@dataclass
class KW:
    """A keyword argument of a generated config call and the plan entry it comes from."""

    name: str
    value: str
    source: str


@dataclass
class Part:
    """A part of the plugin, traced to its plan entry, implementation and evidence."""

    file: str
    role: str
    path: str
    terminal: str
    what: str
    implementation: str
    source: str = ""
    evidence: str = ""


@dataclass
class Names:
    method: str
    package: str
    prefix: str

    @classmethod
    def of(cls, method: str) -> Names:
        package = package_name(method)  # the name validate() checked (plan.method_name_problems)
        prefix = "".join(part.capitalize() for part in package.split("_"))
        return cls(method=method, package=package, prefix=prefix)


@dataclass
class Context:
    """Everything the templates render for one plugin."""

    names: Names
    plan: dict
    derivation: Derivation
    grammar: Grammar
    parts: list[Part] = field(default_factory=list)
    components: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        self.plan = Plan.of(self.plan)

    def params(self, path: str) -> dict:
        """A terminal's parameters at ``path`` with the grammar's defaults filled in."""
        terminal = self.grammar.terminals[self.derivation.used[path]]
        given = self.plan.get(path)
        return {**terminal.defaults(), **(given if isinstance(given, dict) else {})}

    def used(self, path: str) -> bool:
        return path in self.derivation.used

    def part(self, file: str, role: str, path: str, what: str) -> None:
        terminal = self.grammar.terminals[self.derivation.used[path]]
        if terminal.name == CUSTOM:
            entry = self.params(path)
            implementation = f"{self.names.package}.{entry['module']}.{entry['class']}"
            source = f"{entry['source']}-written component" + (
                f" implementing {', '.join(entry['implements'])}" if entry["implements"] else "")
            evidence = entry["evidence"] or self.plan.evidence_for(path)
        else:
            implementation = terminal.implementation.replace("nerfify_ns.components",
                                                             f"{self.names.package}.components")
            source, evidence = card_reference(terminal.card), self.plan.evidence_for(path)
        self.parts.append(Part(file=file, role=role, path=path, terminal=terminal.name, what=what,
                               implementation=implementation, source=source, evidence=str(evidence)))

    def custom(self, slot: str) -> dict | None:
        """The custom component at ``slot`` (a choice or open slot holding ``{custom: {...}}``): its class,
        the import of its module inside the plugin, its constructor arguments as Python source."""
        path = f"{slot}.{CUSTOM}"
        if not self.used(path) or self.derivation.used[path] != CUSTOM:
            return None
        return custom_component(self.params(path), self.names.package)

    def need_component(self, snippet: dict) -> None:
        """The plugin carries the snippet's component module, and the component modules that one imports."""
        pending = [snippet.get("component")]
        while pending:
            module = pending.pop()
            if module and module not in self.components:
                self.components.append(module)
                pending += component_imports(module)


def component_source(module: str) -> str:
    """Our component module as the plugin carries it (so it stands alone): imports of other components relative."""
    source = resources.files("nerfify_ns.components").joinpath(f"{module}.py").read_text()
    return source.replace("from nerfify_ns.components.", "from .").replace("from nerfify_ns.components import",
                                                                           "from . import")


def component_imports(module: str) -> list[str]:
    """The modules of ``nerfify_ns.components`` that the component ``module`` imports."""
    return re.findall(r"^\s*from \.(\w+) import", component_source(module), flags=re.MULTILINE)


def card_reference(card_name: str | None, kb: KnowledgeBase | None = None) -> str:
    """'<paper title> (<year>), <equation>' of a card of the knowledge base ``kb`` (default: the package's),
    or '' when there is none."""
    if not card_name:
        return ""
    try:
        card = kb.card(card_name) if kb is not None else load_card(card_name)
    except NerfifyError:
        return ""
    where = f", {card.equation.ref}" if card.equation.ref else ""
    year = f" ({card.paper.year})" if card.paper.year else ""
    arxiv = f", arXiv {card.paper.arxiv}" if card.paper.arxiv else ""
    return f"{card.paper.title}{year}{arxiv}{where}"


def custom_component(entry: dict, package: str) -> dict:
    """What the templates need of a custom component: class, import line, keyword arguments (source)."""
    kwargs = ", ".join(f"{k}={py(v)}" for k, v in (entry.get("params") or {}).items())
    return {"cls": entry["class"], "module": entry["module"], "kwargs": kwargs,
            "import": f"from .{entry['module']} import {entry['class']}",
            "domain": entry.get("input_domain", "signed_unit"), "weight": entry.get("weight", 1.0)}


def annealed(plan) -> set[str]:
    """What the plan's anneal hooks write (their ``target``)."""
    hooks = plan.get("model.schedule_hooks") if hasattr(plan, "get") else None
    return {str(v.get("target")) for k, v in (hooks or {}).items() if k == "anneal" and isinstance(v, dict)}


def call(cls: str, *args: str) -> str:
    """``Cls(a, b, ...)`` without empty arguments."""
    return f"{cls}({', '.join(a for a in args if a)})"


# ------------------------------------------------------------------------------- the field
def _imports(ctx: Context, snippet: dict) -> list[str]:
    ctx.need_component(snippet)
    return [render_snippet(line, {}, ctx.names.package) for line in snippet.get("imports", [])]


def _activation(kind: str) -> Callable[[str], str]:
    expr = ACTIVATIONS[kind].expr
    return lambda x: render(expr, {}, x=x)


def mlp_field(ctx: Context) -> dict:
    root = "model.field.MLPField"
    fp = ctx.plan.get(root)
    pkg = ctx.names.package
    imports: list[str] = []

    pe_name, _ = one(fp["pos_encoding"])
    pe_path = f"{root}.pos_encoding.{pe_name}"
    ctx.part("field.py", "position encoding", pe_path, ctx.grammar.terminals[pe_name].doc)
    custom_pe = ctx.custom(f"{root}.pos_encoding")
    if custom_pe:
        imports.append(custom_pe["import"])
        pe = {"ctor": call(custom_pe["cls"], custom_pe["kwargs"]), "domain": custom_pe["domain"], "times": False}
    else:
        code = snippet(pe_name)
        imports += _imports(ctx, code)
        pe_params = ctx.params(pe_path)
        pe_sizes = config_sizes(pe_name, pe_params)
        pe = {"ctor": render_snippet(code["ctor"], {**pe_params, **{w["of"]: w["param"] for w in pe_sizes}}, pkg),
              "domain": code["domain"], "times": bool(code.get("times")), "sizes": pe_sizes}
        # the coarse-to-fine window over the encoding's bands (its `schedulable` trait, registry/terminals/
        # encodings.py: coarse_to_fine): the encoding is wrapped in it when an anneal of the plan writes it
        if code.get("window_layout") and annealed(ctx.plan) & set(code.get("schedulable") or ()):
            imports += _imports(ctx, {"imports": ["from .components.encoding_window import CoarseToFine"],
                                      "component": "encoding_window"})
            bands = next((w["param"] for w in pe_sizes if w["of"] == code["window_bands"]),  # a proxy's size too
                         int(pe_params[code["window_bands"]]))
            pe["ctor"] = f"CoarseToFine({pe['ctor']}, bands={bands}, layout={code['window_layout']!r})"

    de_name, _ = one(fp["dir_encoding"])
    de_path = f"{root}.dir_encoding.{de_name}"
    ctx.part("field.py", "direction encoding", de_path, ctx.grammar.terminals[de_name].doc)
    custom_de = ctx.custom(f"{root}.dir_encoding")
    if custom_de:
        imports.append(custom_de["import"])
        de = {"ctor": call(custom_de["cls"], custom_de["kwargs"]), "normalized_input": False}
    else:
        code = snippet(de_name)
        imports += _imports(ctx, code)
        de = {"ctor": render_snippet(code["ctor"], ctx.params(de_path), pkg),
              "normalized_input": code["normalized_input"]}

    dh_name, _ = one(fp["density_head"])
    dh_path = f"{root}.density_head.{dh_name}"
    ctx.part("field.py", "density head", dh_path, ctx.grammar.terminals[dh_name].doc)
    custom_dh = ctx.custom(f"{root}.density_head")
    split = dh_name == "density_split"
    dh = ctx.params(dh_path) if not custom_dh else {}
    if custom_dh:
        imports.append(custom_dh["import"])
    else:
        imports += _imports(ctx, {"imports": list(ACTIVATIONS[dh["activation"]].imports)})

    backbone_path = f"{root}.backbone"
    custom_bb = ctx.custom(backbone_path)
    backbone_path = f"{backbone_path}.custom" if custom_bb else backbone_path
    ctx.part("field.py", "backbone", backbone_path, ctx.grammar.terminals[ctx.derivation.used[backbone_path]].doc)
    backbone = ctx.params(backbone_path) if not custom_bb else {}
    out_dim = str(1 + dh["geo_feat_dim"]) if split else "None"
    wrappers = field_wrappers(ctx)
    imports += wrappers["imports"]
    backbone_in = "self.position_encoding.get_out_dim()" + (" + self.wrapper_dim" if wrappers["conditioners"] else "")
    branches = bool(backbone.get("branches"))
    if custom_bb:
        imports.append(custom_bb["import"])
        backbone_ctor = call(custom_bb["cls"], f"in_dim={backbone_in}", f"out_dim={out_dim}", custom_bb["kwargs"])
    elif branches:
        imports += _imports(ctx, {"imports": ["from .components.mlp_branches import BranchedMLP"],
                                  "component": "mlp_branches"})
        backbone_ctor = call("BranchedMLP", f"in_dim={backbone_in}", "num_layers=num_layers",
                             "layer_width=layer_width",
                             f"skip_connections={py(backbone_skips(backbone)) if backbone_skips(backbone) else None}",
                             *(f"{k}={backbone[k]}" for k in ("density_layers", "density_width", "color_layers",
                                                              "color_width")), 'implementation="tcnn"')
    elif backbone.get("hidden_norm", "none") == "layer":
        imports += _imports(ctx, {"imports": ["from .components.mlp_normed import NormedMLP"],
                                  "component": "mlp_normed"})
        backbone_ctor = call("NormedMLP", f"in_dim={backbone_in}", "num_layers=num_layers",
                             "layer_width=layer_width", f"out_dim={out_dim}",
                             f"skip_connections={py(backbone_skips(backbone)) if backbone_skips(backbone) else None}",
                             f"out_activation={'None' if split else 'nn.ReLU()'}")
    else:
        backbone_ctor = None

    rgb_path = f"{root}.rgb_head"
    custom_rgb = ctx.custom(rgb_path)
    rgb_path = f"{rgb_path}.custom" if custom_rgb else rgb_path
    ctx.part("field.py", "colour head", rgb_path, ctx.grammar.terminals[ctx.derivation.used[rgb_path]].doc)
    rgb = ctx.params(rgb_path) if not custom_rgb else {}

    distortion = None
    if "spatial_distortion" in fp:
        sd_name, _ = one(fp["spatial_distortion"])
        sd_path = f"{root}.spatial_distortion.{sd_name}"
        custom_sd = ctx.custom(f"{root}.spatial_distortion")
        if custom_sd:
            imports.append(custom_sd["import"])
            distortion = call(custom_sd["cls"], custom_sd["kwargs"])
        else:
            code = snippet(sd_name)
            imports += _imports(ctx, code)
            distortion = render_snippet(code["ctor"], ctx.params(sd_path), pkg)
        ctx.part("field.py", "spatial distortion", sd_path, ctx.grammar.terminals[sd_name].doc)

    appearance = None
    if "appearance_embedding" in fp:
        appearance = ctx.params(f"{root}.appearance_embedding")
        imports.append("from nerfstudio.field_components.embedding import Embedding")
        ctx.part("field.py", "appearance embedding", f"{root}.appearance_embedding",
                 ctx.grammar.terminals["appearance_embedding"].doc)

    if custom_dh:
        geo = "self.density_head.get_out_dim()"
    elif branches:
        geo = "self.backbone.color_dim"
    else:
        geo = str(dh["geo_feat_dim"]) if split else "self.backbone.get_out_dim()"
    rgb_in = " + ".join(["self.direction_encoding.get_out_dim()", geo]
                        + ([str(appearance["dim"])] if appearance else []))
    if custom_rgb:
        imports.append(custom_rgb["import"])
        rgb_ctor = call(custom_rgb["cls"], f"in_dim={rgb_in}", custom_rgb["kwargs"])
    else:
        rgb_ctor = None
    skips = list(backbone_skips(backbone)) if backbone else None
    widths = [*(backbone_widths(backbone) if backbone else []), *pe.get("sizes", []), *wrappers["widths"]]
    architecture = (f"{backbone['num_layers']} x {backbone['layer_width']} MLP" if backbone
                    else f"{custom_bb['cls']} backbone")
    if backbone.get("hidden_norm", "none") == "layer":
        architecture += " with layer normalisation after each hidden layer"
    if branches:
        architecture += (f" with a {backbone['density_layers']} x {backbone['density_width']} density branch and a "
                         f"{backbone['color_layers']} x {backbone['color_width']} colour branch")
    return {
        "cls": f"{ctx.names.prefix}Field",
        "widths": widths,
        "kwargs": "".join(f", {w['param']}=self.config.{w['name']}" for w in widths),
        "summary": f"Radiance field of the plan: {pe_name} positions, {de_name} directions, "
                   f"{architecture}, {dh_name} density.",
        "imports": sorted(set(imports)),
        "pos_encoding": pe["ctor"],
        "dir_encoding": de["ctor"],
        "dir_normalized": de["normalized_input"],
        "domain": pe["domain"],
        "times": pe["times"],
        "distortion": distortion,
        "appearance": appearance,
        "backbone": {**backbone, "skip_connections": py(skips) if skips else None, "custom": backbone_ctor,
                     "in_dim": backbone_in, "branches": branches},
        "wrappers": wrappers,
        "member_cls": f"{ctx.names.prefix}FieldMember" if wrappers["blend"] else f"{ctx.names.prefix}Field",
        "density": {"split": split, "geo_feat_dim": dh.get("geo_feat_dim"), "init_density": dh.get("init_density"),
                    "activation": _activation(dh["activation"]) if dh else None,
                    "custom": call(custom_dh["cls"], "in_dim=self.backbone.get_out_dim()", custom_dh["kwargs"])
                    if custom_dh else None},
        "rgb": {**rgb, "custom": rgb_ctor},
        "rgb_in_dim": rgb_in,
        "keeps_density": ctx.used("model.regularizers.density_sparsity") or _custom_regularizers(ctx),
        "shares_samples": _renderer_needs_samples(ctx),
        "parts": [p for p in ctx.parts if p.file == "field.py"],
    }


def backbone_widths(backbone: dict) -> list[dict]:
    """The backbone's depth and width as fields of the generated model config (the plan's values their defaults):
    the field reads them from the config, so a run may train narrower (a CPU proxy) without editing the code."""
    return [{"name": f"mlp_{param}", "param": param, "value": int(backbone[param]), "doc": doc}
            for param, doc in (("num_layers", "Hidden layers of the field's backbone MLP (the plan's value)."),
                               ("layer_width", "Units per hidden layer of the field's backbone MLP (the plan's "
                                               "value; a CPU proxy may train narrower)."))]


def field_wrappers(ctx: Context, file: str = "field.py") -> dict:
    """The plan's field wrappers (``model.field_wrappers``), in the plan's order: conditioners (each built in the
    field, or in a model of Gaussians in ``model.py``: a ``(name, constructor)``; ``part``: the name schedule hooks
    know it by, its terminal's first ``schedulable`` part) and at most one blend (the field then is several copies
    of itself)."""
    path = "model.field_wrappers"
    members = ctx.plan.get(path) or {}
    conditioners: list[dict] = []
    blend: dict | None = None
    imports: list[str] = []
    widths: list[dict] = []
    for name in members:
        member = f"{path}.{name}"
        terminal = ctx.derivation.used.get(member)
        if terminal == CUSTOM:
            entry = ctx.params(member)
            component = custom_component(entry, ctx.names.package)
            imports.append(component["import"])
            ctor = call(component["cls"], "num_images=num_images", component["kwargs"])
            ctx.part(file, "field wrapper", member, ctx.grammar.terminals[CUSTOM].doc)
            if entry.get("wrapper") == "blend":
                if blend is not None:
                    raise NerfifyError(f"{member}: the plan blends its fields twice (one blend per field)")
                imports += _imports(ctx, {"imports": ["from .components.field_wrappers import BlendedField"],
                                          "component": "field_wrappers"})
                blend = {"ctor": ctor, "num_fields": int((entry.get("params") or {}).get("num_fields", 2)),
                         "static_first": False}
            else:
                conditioners.append({"name": name, "ctor": ctor})
            continue
        code = snippet(name)
        imports += _imports(ctx, code)
        params = ctx.params(member)
        sized = config_sizes(name, params)
        widths += sized
        ctor = render_snippet(code["ctor"], {**params, **{w["of"]: w["param"] for w in sized}}, ctx.names.package)
        ctx.part(file, "field wrapper", member, ctx.grammar.terminals[name].doc)
        if code.get("stage") == "blend":
            if blend is not None:
                raise NerfifyError(f"{member}: the plan blends its fields twice (one blend per field)")
            blend = {"ctor": ctor, "num_fields": params["num_fields"], "static_first": params["static_first"]}
        else:
            conditioners.append({"name": name, "ctor": ctor, "part": (code.get("schedulable") or [name])[0]})
    if conditioners:
        imports += _imports(ctx, {"imports": ["from .components.field_wrappers import condition"],
                                  "component": "field_wrappers"})
    return {"conditioners": conditioners, "blend": blend, "imports": imports, "widths": widths}


def config_sizes(terminal: str, params: dict) -> list[dict]:
    """A part's sizes that a CPU proxy may lower (``proxy.yaml``'s ``grid`` and ``width`` entries with a ``config``
    field: a deformation network's width, per-frame codes' dimension, space-time planes' resolutions) as fields of
    the generated model config, the plan's values their defaults: the field builds the part from them (``of``: the
    part's parameter; ``type``: the field's annotation)."""
    spec = proxy_spec()
    entries = {k: v for kind in SIZES for k, v in ((spec.get(kind) or {}).get(terminal) or {}).items()}
    return [{"name": entry["config"], "param": entry["config"], "of": param,
             "value": tuple(int(v) for v in params[param]) if isinstance(params[param], list) else int(params[param]),
             "type": "Tuple[int, ...]" if isinstance(params[param], list) else "int",
             "doc": f"{entry.get('what', 'width').capitalize()} of {terminal} (the plan's value; a CPU proxy may "
                    "train smaller)."}
            for param, entry in entries.items()
            if entry.get("config") and _sized(params.get(param))]


def _sized(value: Any) -> bool:
    """An int, or a non-empty list of ints (not a bool)."""
    if isinstance(value, list):
        return bool(value) and all(_sized(v) for v in value)
    return isinstance(value, int) and not isinstance(value, bool)


def schedule_hooks(ctx: Context) -> tuple[list[dict], list[str]]:
    """The plan's schedule hooks (``model.schedule_hooks``): constructors, and the imports they need."""
    path = "model.schedule_hooks"
    hooks: list[dict] = []
    imports: list[str] = []
    for name in ctx.plan.get(path) or {}:
        member = f"{path}.{name}"
        if ctx.derivation.used.get(member) == CUSTOM:
            component = custom_component(ctx.params(member), ctx.names.package)
            imports.append(component["import"])
            hooks.append({"name": name, "ctor": call(component["cls"], component["kwargs"])})
            ctx.part("model.py", "schedule hook", member, ctx.grammar.terminals[CUSTOM].doc)
            continue
        code = snippet(name)
        imports += _imports(ctx, code)
        hooks.append({"name": name, "ctor": render_snippet(code["ctor"], ctx.params(member), ctx.names.package)})
        ctx.part("model.py", "schedule hook", member, ctx.grammar.terminals[name].doc)
    if hooks:
        imports += _imports(ctx, {"imports": ["from .components.schedule_hooks import training_callbacks",
                                              "from torch import nn"], "component": "schedule_hooks"})
    return hooks, imports


def pixel_sampler(ctx: Context) -> dict | None:
    """The training pixel sampler: the plan's map (``pixel_sampler``), or a uniform map where a schedule hook
    needs the plugin's sampler (an image curriculum) and the plan names none; None for Nerfstudio's own."""
    needs = any(ctx.grammar.terminals[t].code.traits.get("needs_map_sampler")
                for p, t in ctx.derivation.used.items() if p.startswith("model.schedule_hooks."))
    if "pixel_sampler" not in ctx.plan and not needs:
        return None
    imports = _imports(ctx, {"imports": ["from .components.pixel_samplers import MapPixelSampler, "
                                         "MapPixelSamplerConfig"], "component": "pixel_samplers"})
    if "pixel_sampler" not in ctx.plan:
        imports.append("from .components.pixel_samplers import UniformMap")
        ctor, path, what = "UniformMap()", "pixel_sampler (absent: uniform, for the curriculum)", "uniform"
    else:
        name, _ = one(ctx.plan["pixel_sampler"])
        path = f"pixel_sampler.{name}"
        custom = ctx.custom("pixel_sampler")
        if custom:
            imports.append(custom["import"])
            ctor = call(custom["cls"], custom["kwargs"])
        else:
            code = snippet(name)
            imports += _imports(ctx, code)
            ctor = render_snippet(code["ctor"], ctx.params(path), ctx.names.package)
        ctx.part("pixel_sampler.py", "pixel sampler", path, ctx.grammar.terminals[name].doc)
        what = name
    return {"cls": f"{ctx.names.prefix}PixelSampler", "config_cls": f"{ctx.names.prefix}PixelSamplerConfig",
            "map": ctor, "imports": sorted(set(imports)), "source": path, "what": what}


def primitives(ctx: Context) -> dict:
    """A model of explicit primitives (3D Gaussians, no field): the plan's wrappers, applied by the model to the
    Gaussians at the camera's time; a part the template cannot apply to Gaussians (a blend of fields, a regulariser
    of the field's samples) is refused here in one line (the grammar's duties keep such parts out of a valid
    plan)."""
    wrappers = field_wrappers(ctx, file="model.py")
    if wrappers["blend"] is not None:
        raise NerfifyError("a blend of fields in a model of Gaussians: the model has no field to copy")
    if any(ctx.derivation.used.get(f"model.regularizers.{name}") == CUSTOM
           for name in ctx.plan.get("model.regularizers") or {}):
        raise NerfifyError("a regulariser of the plugin in a model of Gaussians: it reads the field's samples, "
                           "which a model of Gaussians has not")
    return {"cls": None, "wrappers": wrappers, "widths": wrappers["widths"]}


def custom_field(ctx: Context) -> dict:
    """A field of the plugin in place of the generated one: the model installs it as it would its own."""
    path = "model.field.custom"
    component = custom_component(ctx.params(path), ctx.names.package)
    ctx.part("model.py", "field", path, ctx.grammar.terminals[CUSTOM].doc)
    kwargs = f", {component['kwargs']}" if component["kwargs"] else ""
    return {"cls": component["cls"], "custom": component["import"], "kwargs": kwargs,
            "parts": [p for p in ctx.parts if p.file == "field.py"]}


def custom_modules(ctx: Context) -> list[str]:
    """The modules of the plugin's components package that custom entries of the plan name."""
    return sorted({ctx.params(path)["module"] for path, term in ctx.derivation.used.items() if term == CUSTOM})


def _renderer_needs_samples(ctx: Context) -> bool:
    """Whether the plan's renderer is a custom component that reads the field's samples and densities (one the
    equation compiler wrote, with ``bind_samples``): the field then shares them."""
    entry = ctx.plan.get("model.renderer.custom")
    return isinstance(entry, dict) and entry.get("source") == "compiler"


def _custom_regularizers(ctx: Context) -> list[str]:
    """Paths of the plan's custom regularisers (they read the field's densities)."""
    return [path for path, term in ctx.derivation.used.items()
            if term == CUSTOM and path.startswith("model.regularizers.")]


def tensorial_field(ctx: Context) -> dict:
    root = "model.field.TensorialField"
    fp = ctx.plan.get(root)
    dec_name, _ = one(fp["decomposition"])
    dec_path = f"{root}.decomposition.{dec_name}"
    dec = ctx.params(dec_path)
    code = snippet(dec_name)
    head = ctx.params(f"{root}.appearance_head")
    ctx.part("field.py", "tensor decomposition", dec_path, ctx.grammar.terminals[dec_name].doc)
    ctx.part("field.py", "appearance head", f"{root}.appearance_head",
             ctx.grammar.terminals["tensorial_appearance"].doc)
    return {
        "cls": f"{ctx.names.prefix}Field",
        "summary": f"Tensorial radiance field of the plan: {dec_name} factors, "
                   f"{dec['density_components']} density / {dec['color_components']} appearance components.",
        "imports": _imports(ctx, code),
        "decomposition": code["cls"],
        "density_components": dec["density_components"],
        "color_components": dec["color_components"],
        **{k: head[k] for k in ("appearance_dim", "num_layers", "layer_width", "feature_frequencies",
                                "direction_frequencies")},
        "keeps_density": ctx.used("model.regularizers.density_sparsity") or _custom_regularizers(ctx),
        "shares_samples": _renderer_needs_samples(ctx),
        "parts": [p for p in ctx.parts if p.file == "field.py"],
    }


# ------------------------------------------------------------------------------- the model
def _proposal_networks(ctx: Context) -> dict | None:
    path = "model.sampler.proposal"
    if not ctx.used(path) or ctx.params(path)["network"] != "kplanes":
        return None
    distortion = ctx.used("model.field.MLPField.spatial_distortion.scene_contraction")
    ctor = "KPlanesDensityField(self.scene_box.aabb, resolution=resolution, num_components=8"
    ctor += ', spatial_distortion=SceneContraction(order=float("inf")))' if distortion else ")"
    imports = ["from .components.kplanes import KPlanesDensityField", "from torch import nn"]
    if distortion:
        imports.append("from nerfstudio.field_components.spatial_distortions import SceneContraction")
    ctx.need_component({"component": "kplanes"})
    return {"ctor": ctor, "resolutions": proposal_resolutions(ctx.params(path)), "imports": imports}


def _planes_attr(ctx: Context, base: dict) -> str | None:
    """The model attribute a regulariser's expression reads as ``field`` (its ``position_encoding``): the base's
    field, or the wrapper whose encoding holds the plan's feature planes (a deformation of Gaussians over planes)."""
    owner = plane_owner(ctx.plan)
    if owner and owner.startswith("model.field_wrappers."):
        name = owner.rpartition(".")[2]
        return f'self.wrappers["{((snippet(name) or {}).get("schedulable") or [name])[0]}"]'
    return base.get("field_attr")


def model_context(ctx: Context) -> dict:
    imports: list[str] = []
    base = bases()[ctx.plan["base"]]
    rgb_name, _ = one(ctx.plan.get("model.losses.rgb"))
    rgb_path = f"model.losses.rgb.{rgb_name}"
    ctx.part("model.py", "photometric loss", rgb_path, ctx.grammar.terminals[rgb_name].doc)
    rgb_loss, custom_loss = None, ctx.custom("model.losses.rgb")
    if custom_loss:
        imports.append(custom_loss["import"])
        rgb_loss = {"name": custom_loss["cls"], "ctor": call(custom_loss["cls"], custom_loss["kwargs"])}
    elif snippet(rgb_name):
        code = snippet(rgb_name)
        imports += _imports(ctx, code)
        rgb_loss = {"name": rgb_name, "ctor": render_snippet(code["ctor"], ctx.params(rgb_path), ctx.names.package)}
    regularizers, modules = [], []
    planes = _planes_attr(ctx, base)
    for name in (ctx.plan.get("model").get("regularizers") or {}):
        path = f"model.regularizers.{name}"
        if ctx.derivation.used.get(path) == CUSTOM:
            component = custom_component(ctx.params(path), ctx.names.package)
            imports.append(component["import"])
            modules.append({"attr": name, "ctor": call(component["cls"], component["kwargs"])})
            regularizers.append({"name": name, "weight": component["weight"],
                                 "expr": f"self.{name}(densities={base['field_attr']}.last_density, "
                                         f"deltas={base['field_attr']}.last_deltas, "
                                         f"weights=getattr({base['field_attr']}, 'last_weights', None))"})
            ctx.part("model.py", "regulariser", path, ctx.grammar.terminals[CUSTOM].doc)
            continue
        code = snippet(name)
        if code is None:  # realised through the base model's own config (e.g. TensoRF's L1/TV)
            continue
        params = ctx.params(path)
        imports += _imports(ctx, code)
        regularizers.append({"name": name, "weight": params["weight"],
                             "expr": render(code["expr"], params, ctx.names.package, field=planes)})
        ctx.part("model.py", "regulariser", path, ctx.grammar.terminals[name].doc)
    if ctx.plan.get("model.sampler"):
        sampler_name, _ = one(ctx.plan.get("model.sampler"))
        ctx.part("model.py", "sampler", f"model.sampler.{sampler_name}", ctx.grammar.terminals[sampler_name].doc)
    custom_sampler = ctx.custom("model.sampler")
    if custom_sampler:
        imports.append(custom_sampler["import"])
        sampler = base["importance_sampler"]
        modules.append({"attr": sampler["attr"], "ctor": call(
            custom_sampler["cls"], f"num_samples=self.config.{sampler['num_samples']}", custom_sampler["kwargs"])})
    custom_renderer = ctx.custom("model.renderer")
    if custom_renderer:
        imports.append(custom_renderer["import"])
        modules.append({"attr": "renderer_rgb", "ctor": call(
            custom_renderer["cls"], "background_color=self.config.background_color", custom_renderer["kwargs"])})
        ctx.part("model.py", "renderer", "model.renderer.custom", ctx.grammar.terminals[CUSTOM].doc)
    proposal = _proposal_networks(ctx)
    if proposal:
        imports += proposal["imports"]
    sampler_code = (snippet(sampler_name) or {}) if ctx.plan.get("model.sampler") and not custom_sampler else {}
    wrap = sampler_code.get("schedule_wrap")
    if wrap and annealed(ctx.plan) & set(sampler_code.get("schedulable") or ()):
        # the sampler's part an anneal of the plan writes (its `schedulable` trait: the occupancy grid's threshold)
        imports += _imports(ctx, wrap)
        modules.append({"attr": wrap["attr"], "ctor": wrap["ctor"]})
    # the sampler's values the generated config declares (its `config_fields` trait: a proxy may lower them) and
    # what the model sets from them before the base builds itself (`before_base`)
    sampler_params = ctx.params(f"model.sampler.{sampler_name}") if sampler_code else {}
    config_fields = [{"name": f["name"], "type": "int", "value": int(sampler_params[f["param"]]), "doc": f["doc"]}
                     for f in sampler_code.get("config_fields") or ()]
    hooks, hook_imports = schedule_hooks(ctx)
    imports += hook_imports
    from nerfify_ns.components.schedule_hooks import STEP_SCALE_FIELD  # the plugin's own name for it (torch: on use)

    return {
        "hooks": hooks,
        "step_scale_field": STEP_SCALE_FIELD,
        "renderer_samples": bool(custom_renderer) and _renderer_needs_samples(ctx),
        "cls": f"{ctx.names.prefix}Model",
        "config_cls": f"{ctx.names.prefix}ModelConfig",
        "imports": sorted(set(imports)),
        "rgb_loss": rgb_loss,
        "regularizers": regularizers,
        "modules": modules,
        "proposal_networks": proposal,
        "config_fields": config_fields,
        "before_base": list(sampler_code.get("before_base") or ()),
    }


# ------------------------------------------------------------------------------- the config
def _config_fields(base: dict) -> dict[str, Any]:
    module = importlib.import_module(base.get("config_module") or base["module"])
    cls = getattr(module, base["config_class"])
    return {f.name: f for f in dataclasses.fields(cls)}


def _mapped_values(ctx: Context, base_name: str) -> list[KW]:
    """Base-config values that terminals map onto (``config:`` in grammar_spec.yaml)."""
    out = []
    for path, term in ctx.derivation.used.items():
        mapping = ctx.grammar.terminals[term].config.get(base_name, {})
        params = ctx.params(path) if mapping else {}
        for param, config_field in mapping.items():
            out.append(KW(config_field, py(params[param]), f"{path}.{param}"))
    return out


def _derived_values(ctx: Context, base_name: str, fields: dict[str, Any]) -> list[KW]:
    """Base-config switches implied by what the plan contains (or leaves out)."""
    out: list[KW] = []
    model = ctx.plan.get("model")
    mlp = ((model.get("field") or {}).get("MLPField") or {})
    if "background_color" in fields and not ctx.custom("model.renderer"):
        out.append(KW("background_color", py(ctx.params("model.renderer")["background"]), "model.renderer.background"))
    elif "background_color" in fields and ctx.plan.get("model.renderer.custom.params.background"):
        out.append(KW("background_color", py(ctx.plan.get("model.renderer.custom.params.background")),
                      "model.renderer.custom.params.background"))
    if "disable_scene_contraction" in fields:
        out.append(KW("disable_scene_contraction", py("spatial_distortion" not in mlp),
                      "model.field.MLPField.spatial_distortion (absent: disabled)"))
    if "use_appearance_embedding" in fields:
        has = "appearance_embedding" in mlp
        inverted = "use_appearance_embedding" in bases()[base_name].get("inverted_flags", [])
        out.append(KW("use_appearance_embedding", py(has != inverted),
                      "model.field.MLPField.appearance_embedding"
                      + (" (the base inverts this flag)" if inverted else "")))
    if "average_init_density" in fields and ctx.used("model.field.MLPField.density_head.density_split"):
        value = ctx.params("model.field.MLPField.density_head.density_split")["init_density"]
        out.append(KW("average_init_density", py(value),
                      "model.field.MLPField.density_head.density_split.init_density"))
    if "camera_optimizer" in fields:
        mode = {"so3xr3": "SO3xR3", "se3": "SE3"}.get(one(model["camera_optimizer"])[0]) \
            if "camera_optimizer" in model else "off"
        out.append(KW("camera_optimizer", f"CameraOptimizerConfig(mode={mode!r})",
                      "model.camera_optimizer (absent: off)"))
    if ctx.used("model.sampler.proposal") and "proposal_net_args_list" in fields:
        p = ctx.params("model.sampler.proposal")
        out.append(KW("num_proposal_iterations", py(len(p["samples_per_ray"])),
                      "model.sampler.proposal.samples_per_ray"))
    if ctx.used("model.sampler.proposal"):
        # Also for k-planes proposal networks, which replace the base's: Nerfacto builds its own first, one per
        # round or exactly one with use_same_proposal_network (it asserts a one-entry list then).
        p = ctx.params("model.sampler.proposal")
        nets = [{"hidden_dim": p["network_hidden_dim"], "log2_hashmap_size": p["network_log2_hashmap_size"],
                 "num_levels": p["network_num_levels"], "max_res": r, "use_linear": False}
                for r in proposal_resolutions(p)]
        out.append(KW("proposal_net_args_list", "[" + ", ".join(py(n) for n in nets) + "]",
                      "model.sampler.proposal.network_*"))
    out += _loss_coefficients(ctx, base_name, fields)
    return out


def _loss_coefficients(ctx: Context, base_name: str, fields: dict[str, Any]) -> list[KW]:
    """The base config's loss coefficients: as the base's definition gives them (``loss_coefficients`` in
    ``registry/bases.yaml``, each a number or a plan path), or TensoRF's from its decomposition and regularisers
    (a base config with ``tensorf_encoding`` and ``regularization``)."""
    given = bases()[base_name].get("loss_coefficients")
    if given:
        values = {k: ctx.params(v.rsplit(".", 1)[0])[v.rsplit(".", 1)[1]] if isinstance(v, str) else v
                  for k, v in given.items()}
        return [KW("loss_coefficients", py(values), ", ".join(v for v in given.values() if isinstance(v, str)))]
    if "tensorf_encoding" not in fields or "regularization" not in fields:
        return []
    dec, _ = one(ctx.plan.get("model.field.TensorialField.decomposition"))
    out = [KW("tensorf_encoding", py({"tensor_vm": "vm", "tensor_cp": "cp"}[dec]),
              "model.field.TensorialField.decomposition")]
    coeffs = {"rgb_loss": 1.0}
    regularization = "none"
    if ctx.used("model.regularizers.tensor_tv"):
        p = ctx.params("model.regularizers.tensor_tv")
        regularization = "tv"
        coeffs = {**coeffs, "tv_reg_density": p["density_weight"], "tv_reg_color": p["color_weight"]}
    if ctx.used("model.regularizers.tensor_l1"):
        regularization, coeffs = "l1", {**coeffs, "l1_reg": ctx.params("model.regularizers.tensor_l1")["weight"]}
    out.append(KW("regularization", py(regularization), "model.regularizers (tensor_l1 / tensor_tv)"))
    out.append(KW("loss_coefficients", py(coeffs), "model.regularizers.tensor_*"))
    return out


def _group_ctor(ctx: Context, kind: str, value: dict | None, path: str) -> tuple[str, list[str]]:
    if value is None:
        return "None", []
    name, _ = one(value)
    code = snippet(name)
    return render_snippet(code["ctor"], ctx.params(f"{path}.{name}"), ctx.names.package), code["imports"]


def config_context(ctx: Context, base: dict) -> dict:
    base_name = ctx.plan["base"]
    fields = _config_fields(base)
    trainer = ctx.params("trainer")
    dm = ctx.params("datamanager")
    dataparser = dataparser_snippet(dm["dataparser"])
    sampler = pixel_sampler(ctx)
    datamanager = dict(base["datamanager"])
    if sampler is not None:  # sampled in this process, where a schedule hook can reach the sampler
        datamanager = {"module": "nerfstudio.data.datamanagers.base_datamanager", "cls": "VanillaDataManagerConfig"}
    imports = [
        "from nerfstudio.configs.base_config import ViewerConfig",
        "from nerfstudio.engine.trainer import TrainerConfig",
        "from nerfstudio.plugins.types import MethodSpecification",
        f"from {base['pipeline']['module']} import {base['pipeline']['cls']}",
        f"from {datamanager['module']} import {datamanager['cls']}",
        *dataparser["imports"],
    ]
    if sampler is not None:
        imports.append(f"from .pixel_sampler import {sampler['config_cls']}")
    model_kws = _mapped_values(ctx, base_name) + _derived_values(ctx, base_name, fields)
    if any(kw.name == "camera_optimizer" for kw in model_kws):
        imports.append("from nerfstudio.cameras.camera_optimizers import CameraOptimizerConfig")
    groups = []
    for name, group in ctx.plan["optimizers"].items():
        optimizer, opt_imports = _group_ctor(ctx, "optimizer", group["optimizer"], f"optimizers.{name}.optimizer")
        scheduler, sch_imports = _group_ctor(ctx, "scheduler", group.get("scheduler"), f"optimizers.{name}.scheduler")
        imports += opt_imports + sch_imports
        groups.append({"name": name, "optimizer": optimizer, "scheduler": scheduler})
    return {
        "var": f"{ctx.names.package}_method",
        "imports": sorted(set(imports)),
        "trainer": [KW(k, py(v), f"trainer.{k}") for k, v in trainer.items()],
        "datamanager_cls": datamanager["cls"],
        "datamanager": [KW(k, py(dm[k]), f"datamanager.{k}")
                        for k in ("train_num_rays_per_batch", "eval_num_rays_per_batch")
                        if not base.get("whole_images")]  # a data manager of whole images draws no rays
        + ([KW("pixel_sampler", f"{sampler['config_cls']}()", sampler["source"])] if sampler else []),
        "pixel_sampler": sampler,
        "dataparser": dataparser["ctor"],
        "model": model_kws,
        "optimizers": groups,
    }


def build_context(ctx: Context) -> dict:
    """The full template context of a plugin."""
    base = {"name": ctx.plan["base"], "config_module": None, **bases()[ctx.plan["base"]]}
    if "field" in ctx.plan["model"]:
        field_kind, _ = one(ctx.plan["model"]["field"])
        field_ctx = {"MLPField": mlp_field, "TensorialField": tensorial_field, CUSTOM: custom_field}[field_kind](ctx)
    else:  # a base of explicit primitives (splatfacto): its model applies the wrappers to the Gaussians
        field_kind, field_ctx = None, primitives(ctx)
    field_ctx.setdefault("custom", None)
    field_ctx.setdefault("kwargs", "")
    model = model_context(ctx)
    config = config_context(ctx, base)
    paper = ctx.plan.get("paper") or {}
    return {
        "method": ctx.names.method,
        "package": ctx.names.package,
        "distribution": f"nerfify-{ctx.names.method}",
        "title": ctx.names.method,
        "description": ctx.plan.get("description") or f"{ctx.names.method}, generated by nerfify-ns",
        "paper": paper,
        "base": base,
        "field": field_ctx,
        "field_template": {"MLPField": "field_mlp.py.j2", "TensorialField": "field_tensorial.py.j2"}.get(field_kind),
        "model_template": base.get("template", "model.py.j2"),
        "pixel_sampler": config["pixel_sampler"],
        "model": model,
        "config": config,
        "components": list(ctx.components),
        "custom_modules": custom_modules(ctx),
        "packages": [ctx.names.package] + ([f"{ctx.names.package}.components"]
                                           if ctx.components or custom_modules(ctx) else []),
    }
