"""What the pipeline is given when ``--llm`` is on: one :class:`Agents` object for the run (the injection point;
the pipeline itself never imports this package).

It holds the client (provider, cache, ledger), runs the planner, the coder and the critic, keeps their records,
turns every failure into one warning line (the deterministic result stands), stops asking after an endpoint
failure that retries did not cure (it would fail the same way again), and writes ``agents.json`` into the run
folder: the endpoint (never a key), what each agent did, and the calls, cache hits, tokens and cost per stage
and per hole, which the report shows.
"""

from __future__ import annotations

import json
import logging
import tempfile
from pathlib import Path
from typing import Any

from nerfify_ns import runfolder
from nerfify_ns.agents.cache import ResponseCache
from nerfify_ns.agents.client import Client
from nerfify_ns.agents.config import LLMConfig
from nerfify_ns.agents.providers import Provider, make_provider
from nerfify_ns.agents.usage import Ledger

LOG = logging.getLogger("nerfify.agents")
FILE = runfolder.AGENTS


class Agents:
    """The model-backed agents of one run (see the module docstring)."""

    def __init__(self, config: LLMConfig, provider: Provider | None = None,
                 cache: ResponseCache | None = None, *, context_chars: int = 6000, examples: int = 2) -> None:
        self.config = config
        self.provider = provider or make_provider(config)
        self.cache = cache if cache is not None else ResponseCache(config.cache_path())
        self.ledger = Ledger(config.model, config.costs_nothing, config.run_tokens, config.stage_tokens, config.run_usd)
        self.client = Client(config, self.provider, self.cache, self.ledger)
        self.context_chars, self.examples = context_chars, examples
        self.warnings: list[str] = []
        self.down: str = ""
        self.skipped: list[str] = []
        self.planner: dict | None = None
        self.coder: list[dict] = []
        self.critic_used = False

    @classmethod
    def from_config(cls, config: LLMConfig) -> Agents:
        return cls(config)

    # ------------------------------------------------------------------ warnings
    def warn(self, text: str) -> None:
        line = " ".join(str(text).split())
        self.warnings.append(line)
        LOG.warning(line)

    def _skip(self, what: str) -> bool:
        if self.down:  # said once already, by the warning of the failure itself
            self.skipped.append(f"{what}: not asked, the endpoint failed earlier")
            return True
        return False

    # ------------------------------------------------------------------ the agents
    def plan(self, doc: Any, derived: Any) -> Any:
        """The planner's merged plan (the deterministic one when the model fails: one warning)."""
        from nerfify_ns.agents.planner import run_planner

        if self._skip("planner"):
            return derived.plan
        result = run_planner(self.client, doc, derived, context_chars=self.context_chars, examples=self.examples)
        self.planner = result.to_dict()
        if result.warning:
            self.warn(result.warning)
            if result.endpoint_failed:
                self.down = result.warning
        return result.plan

    def code(self, implementation: Any, *, work: Path | None = None, scene: Any = None, smoke: bool = False,
             timeout: float = 300) -> list[dict]:
        """The coder on every hole the compiler left; updates ``implementation`` in place."""
        from nerfify_ns.agents.coder import code_holes

        if self._skip("coder"):
            return []
        with tempfile.TemporaryDirectory(prefix="nerfify-coder-") as tmp:
            results = code_holes(self.client, implementation, Path(work or tmp), rounds=self.config.coder_rounds,
                                 smoke=smoke, scene=scene, timeout=timeout)
        self.coder = [r.to_dict() for r in results]
        for r in results:
            if r.status in ("error", "rejected"):
                self.warn(f"llm coder ({r.hole}): {r.reason}; the compiler's result stands")
            if r.endpoint_failed:
                self.down = r.reason
        return self.coder

    def critic(self) -> Any:
        from nerfify_ns.agents.critic import ModelCritic

        self.critic_used = True
        return ModelCritic(self.client, self.config.info.images, self.warn)

    # ------------------------------------------------------------------ the record
    def to_dict(self) -> dict:
        return {"endpoint": self.config.describe(), "usage": self.ledger.to_dict(), "warnings": self.warnings,
                "skipped": self.skipped, "planner": self.planner, "coder": self.coder, "critic": self.critic_used}

    def write(self, folder: Path) -> Path:
        path = Path(folder) / FILE
        path.write_text(json.dumps(self.to_dict(), indent=2, default=str))
        return path

    def summary(self) -> str:
        t = self.ledger.total()
        cost = "cost unknown" if t.cost_usd is None else f"{t.cost_usd:.4f} USD"
        return f"llm: {t.calls} call(s), {t.cache_hits} cache hit(s), {t.tokens} tokens, {cost}"
