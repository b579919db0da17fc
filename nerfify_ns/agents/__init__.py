"""Model-backed agents, an option a user turns on with any endpoint (``ns-nerfify PAPER --llm BACKEND:MODEL``).

The deterministic path stays the default and the fallback; every verdict stays computed from runs (the ladder,
training, the patch loop's measured gain), never written by a model. Nothing here is imported unless ``--llm`` is
given, and the provider SDKs (``pip install nerfify-ns[llm]``) only when a call is made.

    from nerfify_ns.agents import Agents, LLMConfig
    agents = Agents.from_config(LLMConfig.parse("openai:gpt-4o-mini", base_url=None))
    agents.plan(doc, derived, kb)              # planner: grammar-constrained plan merged with the detections
    agents.code(doc, implementation)           # coder: the holes the equation compiler left, checked by the ladder
    agents.critic()                            # critic for the patch loop (plan patches in its own format)

Modules: ``backends.yaml`` / ``backends.py`` (the capability table: how each backend takes structured output,
whether it reads images, its key's environment variable, prices where known), ``providers.py`` (one small
interface over the ``openai`` and ``anthropic`` SDKs, plus a scripted model), ``client.py`` (finish reason,
salvage, validation, bounded retries with backoff, budget), ``cache.py`` (content-addressed sqlite response
cache), ``usage.py`` (tokens, calls, cache hits, cost; per-run and per-stage budgets), ``planner.py``,
``coder.py``, ``critic.py``, ``session.py`` (what the pipeline is given: :class:`Agents`).
"""

from nerfify_ns.agents.errors import AgentError, BudgetExceeded, LLMSetupError, ProviderError

__all__ = ["Agents", "AgentError", "BudgetExceeded", "LLMConfig", "LLMSetupError", "ProviderError"]


def __getattr__(name: str):
    """``Agents`` and ``LLMConfig`` on first use (importing the package costs nothing more than its errors)."""
    if name == "Agents":
        from nerfify_ns.agents.session import Agents

        return Agents
    if name == "LLMConfig":
        from nerfify_ns.agents.config import LLMConfig

        return LLMConfig
    raise AttributeError(name)
