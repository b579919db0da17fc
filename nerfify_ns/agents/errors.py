"""Typed errors of the agents: each message is one line naming the problem and what to do."""

from nerfify_ns.errors import NerfifyError


class AgentError(NerfifyError):
    """A model-backed step could not give an answer; the run goes on with the deterministic result."""


class LLMSetupError(AgentError):
    """``--llm`` is malformed, its SDK is not installed or its key is missing (bad input: exit 2)."""


class ProviderError(AgentError):
    """The endpoint failed: ``kind`` is timeout, connection, http, not-json, too-large, truncated, refused or empty."""

    def __init__(self, kind: str, message: str, *, retry: bool = False) -> None:
        super().__init__(message)
        self.kind, self.retry = kind, retry


class InvalidAnswer(AgentError):
    """The model answered, but not with what was asked (not JSON even after repair, or rejected by our grammar /
    schema / checks)."""

    def __init__(self, message: str, problems: list) -> None:
        super().__init__(message)
        self.problems = problems


class BudgetExceeded(AgentError):
    """The run's or a stage's budget (tokens, money) is spent: the agents stop with what was done so far."""
