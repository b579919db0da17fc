"""Ablations: switches that turn one stage of the pipeline off, honoured by the pipeline itself.

A leaf module (standard library only). The paper's Table 5 ablates the knowledge sources (in-context examples,
citation recovery), validation and feedback (smoke tests, visual feedback) and the planning strategy (one-shot
generation instead of the Graph-of-Thought file DAG). Here each is a real switch of ``run_paper`` (and of
``ns-nerfify PAPER --ablate NAME``), not a benchmark-only code path:

==================  ===========================================================================================
name                what the pipeline does without it
==================  ===========================================================================================
no-reference-plans  the plan starts from the knowledge base's plainest base (its first), not from the reference
                    plan (``method_configs/``) the paper states or whose techniques it uses best
no-citations        no citation recovery: the paper's references and "we adopt X from [k]" sentences are not
                    followed; only techniques detected in the paper's own text are used
no-verify           no verification ladder (static, contract, stability, smoke): the plugin is trained as written
no-visual-feedback  no patch loop after the first evaluation (whatever ``--patch-rounds`` says)
no-equations        no equation compiler: every hole of the plan keeps the base's part
no-agents           no model agents: every stage runs its deterministic implementation only
one-shot            the plugin's files are rendered in one pass from the same context, in declaration order,
                    with no per-file parse/format check (instead of the file DAG's topological order)
==================  ===========================================================================================
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, fields

from nerfify_ns.errors import NerfifyError


class AblationError(NerfifyError):
    """An ablation name that does not exist."""


@dataclass(frozen=True)
class Ablation:
    """One ablation: its name (as the command line spells it), the flag's field and its Table 5 label."""

    name: str
    """Name on the command line (``--ablate no-citations``)."""
    label: str
    """Row label in the Table 5 layout."""
    group: str
    """Table 5 group (knowledge sources, validation and feedback, planning strategy)."""
    stage: str
    """The pipeline stage it changes."""


ABLATIONS: tuple[Ablation, ...] = (
    Ablation("no-reference-plans", "w/o in-context reference plans", "Knowledge sources", "read"),
    Ablation("no-citations", "w/o citation recovery", "Knowledge sources", "read"),
    Ablation("no-verify", "w/o verification ladder (smoke tests)", "Validation & feedback", "verify"),
    Ablation("no-visual-feedback", "w/o visual feedback (patch loop)", "Validation & feedback", "patches"),
    Ablation("no-equations", "w/o equation compiler", "Novel parts", "equations"),
    Ablation("no-agents", "w/o model agents", "Novel parts", "read"),
    Ablation("one-shot", "one-shot composition (no file DAG)", "Planning strategy", "plugin"),
)
"""Every ablation, in the order of the Table 5 layout."""
NAMES = tuple(a.name for a in ABLATIONS)


@dataclass(frozen=True)
class Ablations:
    """Which stages are switched off (all False: the full pipeline)."""

    reference_plans: bool = True
    """Start the plan from the best reference plan (False: the plainest base)."""
    citations: bool = True
    """Follow the paper's citations (False: only the paper's own text)."""
    verify: bool = True
    """Run the verification ladder (False: train the plugin as written)."""
    visual_feedback: bool = True
    """Run the patch loop when patch rounds are asked for."""
    equations: bool = True
    """Compile the paper's novel parts from its equations."""
    agents: bool = True
    """Let model agents (when configured) take part."""
    dag: bool = True
    """Compose the plugin file by file in the DAG's topological order (False: one shot)."""

    @classmethod
    def of(cls, names: Iterable[str]) -> Ablations:
        """The switches for ablation ``names`` (``no-citations``, ...); an unknown name is an :class:`AblationError`
        naming the known ones."""
        off = {}
        for name in names:
            name = name.strip()
            if not name:
                continue
            if name not in _FIELD:
                raise AblationError(f"unknown ablation {name!r}; known: {', '.join(NAMES)}")
            off[_FIELD[name]] = False
        return cls(**off)

    @classmethod
    def parse(cls, text: str) -> Ablations:
        """From a comma-separated list (``no-citations,one-shot``)."""
        return cls.of(text.split(","))

    @property
    def names(self) -> tuple[str, ...]:
        """The ablations switched on (stages off), in table order."""
        return tuple(n for n in NAMES if not getattr(self, _FIELD[n]))

    @property
    def full(self) -> bool:
        return all(getattr(self, f.name) for f in fields(self))


_FIELD = {"no-reference-plans": "reference_plans", "no-citations": "citations", "no-verify": "verify",
          "no-visual-feedback": "visual_feedback", "no-equations": "equations", "no-agents": "agents",
          "one-shot": "dag"}
FULL = Ablations()


def ablation(name: str) -> Ablation:
    """The :class:`Ablation` called ``name``."""
    for a in ABLATIONS:
        if a.name == name:
            return a
    raise AblationError(f"unknown ablation {name!r}; known: {', '.join(NAMES)}")
