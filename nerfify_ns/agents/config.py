"""``--llm BACKEND:MODEL`` and its settings, checked before anything runs (a bad one is bad input)."""

from __future__ import annotations

import os
from dataclasses import dataclass, replace
from pathlib import Path

from nerfify_ns.agents.backends import Backend, backends
from nerfify_ns.agents.errors import LLMSetupError

DEFAULT_CACHE = Path("~/.cache/nerfify-ns/llm-cache.sqlite")
"""Where responses are cached unless ``--llm-cache`` or ``$NERFIFY_LLM_CACHE`` says otherwise."""


@dataclass(frozen=True)
class LLMConfig:
    """How the agents reach a model. Keys are never held here: only the name of their environment variable."""

    backend: str
    """Backend of the capability table (``backends.yaml``): openai, compatible, vllm, ollama, llamacpp, anthropic,
    scripted."""
    model: str
    """The model's name at the endpoint (for ``scripted``: the answers file)."""
    base_url: str | None = None
    """The endpoint (OpenAI-compatible servers: ``http://HOST:PORT/v1``); default: the backend's."""
    timeout: float = 120.0
    """Seconds one request may take in all (connecting, sending, the whole answer however slowly it arrives)
    before it is abandoned (and retried)."""
    max_body: int = 32 << 20
    """Bytes one response may hold (headers included); a larger one is refused while it arrives."""
    retries: int = 2
    """Retries of a failed request (timeout, connection, 5xx, HTML, truncated or invalid answer), with backoff."""
    backoff: float = 1.0
    """Seconds before the first retry; doubled at each one."""
    max_tokens: int = 4096
    """Tokens one answer may take (an answer cut at this length is not an answer)."""
    temperature: float = 0.0
    """Sampling temperature (0: greedy, reproducible where the backend allows)."""
    seed: int = 0
    """Sampling seed sent where the backend honours one."""
    run_tokens: int | None = 200_000
    """Token budget of the whole run (input + output, cache hits excluded); None: no limit."""
    stage_tokens: int | None = None
    """Token budget of each stage (planner, coder, critic); None: only the run's."""
    run_usd: float | None = None
    """Money budget of the run in USD, where the model's price is known; None: no limit."""
    cache: Path | None = None
    """The response cache (sqlite); default ``$NERFIFY_LLM_CACHE`` or ``~/.cache/nerfify-ns/llm-cache.sqlite``."""
    constrained: bool = True
    """Send the grammar's constraint (JSON Schema or GBNF) where the backend takes one; off: validate only."""
    coder_rounds: int = 3
    """Rounds of the coder per hole (answer, ladder, diagnosis back), before it stops with the diagnosis."""

    @classmethod
    def parse(cls, spec: str, base_url: str | None = None, **settings) -> LLMConfig:
        """``BACKEND:MODEL`` (``openai:gpt-4o-mini``, ``llamacpp:smollm2``, ``anthropic:claude-3-5-haiku-latest``);
        a bare ``openai:`` model with a ``base_url`` is an OpenAI-compatible server."""
        backend, sep, model = (spec or "").partition(":")
        table = backends()
        if not sep or not model or backend not in table:
            raise LLMSetupError(f"--llm {spec!r}: expected BACKEND:MODEL with BACKEND one of "
                                f"{', '.join(sorted(table))} (e.g. openai:gpt-4o-mini)")
        if backend == "openai" and base_url:
            backend = "compatible"  # OpenAI's own structured-output promise does not hold for another server
        config = cls(backend=backend, model=model, base_url=base_url, **settings)
        config.check()
        return config

    @property
    def info(self) -> Backend:
        return backends()[self.backend]

    @property
    def endpoint(self) -> str | None:
        return self.base_url or self.info.base_url

    def check(self) -> None:
        """Refuse what cannot work before anything runs: a non-positive setting, a missing key."""
        for name in ("timeout", "max_tokens", "coder_rounds", "max_body"):
            if getattr(self, name) <= 0:
                raise LLMSetupError(f"--llm-{name.replace('_', '-')} must be positive, got {getattr(self, name)}")
        if self.retries < 0:
            raise LLMSetupError(f"--llm-retries must be >= 0, got {self.retries}")
        if self.endpoint and not str(self.endpoint).startswith(("http://", "https://")):
            raise LLMSetupError(f"--llm-base-url {self.endpoint!r}: expected http://HOST:PORT/v1")
        info = self.info
        if info.key_required and not self.base_url and not os.environ.get(info.key_env or ""):
            raise LLMSetupError(f"--llm {self.backend}:{self.model} needs a key in ${info.key_env} (keys are read "
                                "only from the environment)")

    def api_key(self) -> str:
        """The key from the environment (a placeholder for local servers that ignore it); never stored."""
        info = self.info
        return os.environ.get(info.key_env or "", "") or "not-needed"

    @property
    def costs_nothing(self) -> bool:
        """A local backend, or any endpoint on a loopback address: its calls cost no money."""
        from urllib.parse import urlparse

        host = urlparse(self.endpoint or "").hostname or ""
        return self.info.local or host == "localhost" or host.startswith("127.") or host == "::1"

    def cache_path(self) -> Path:
        return Path(self.cache or os.environ.get("NERFIFY_LLM_CACHE") or DEFAULT_CACHE).expanduser()

    def with_(self, **changes) -> LLMConfig:
        return replace(self, **changes)

    def describe(self) -> dict:
        """What the report and the cache may say about the endpoint: never the key."""
        return {"backend": self.backend, "model": self.model, "base_url": self.endpoint,
                "structured": self.info.structured if self.constrained else "none",
                "max_tokens": self.max_tokens, "temperature": self.temperature, "retries": self.retries,
                "timeout": self.timeout}
