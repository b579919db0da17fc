"""What the agents spent, per stage (``planner``, ``coder:<hole>``, ``critic``): calls, cache hits, tokens, cost;
and the budgets (per run, per stage; tokens, and money where the model's price is known) checked before each
call, so a spent budget stops the agents cleanly with what was done so far."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

from nerfify_ns.agents.backends import price
from nerfify_ns.agents.errors import BudgetExceeded


@dataclass
class Spent:
    calls: int = 0
    cache_hits: int = 0
    failures: int = 0
    input_tokens: int = 0
    output_tokens: int = 0
    cost_usd: float | None = 0.0
    """None when the model's price is not known (a local model's is 0)."""

    @property
    def tokens(self) -> int:
        return self.input_tokens + self.output_tokens

    def add(self, other: Spent) -> None:
        self.calls += other.calls
        self.cache_hits += other.cache_hits
        self.failures += other.failures
        self.input_tokens += other.input_tokens
        self.output_tokens += other.output_tokens
        self.cost_usd = None if self.cost_usd is None or other.cost_usd is None else self.cost_usd + other.cost_usd

    def to_dict(self) -> dict:
        out = asdict(self)
        out["tokens"] = self.tokens
        if out["cost_usd"] is not None:
            out["cost_usd"] = round(out["cost_usd"], 6)
        return out


@dataclass
class Ledger:
    """Spending per scope (``stage`` or ``stage:item``) and the budgets."""

    model: str
    local: bool
    run_tokens: int | None = None
    stage_tokens: int | None = None
    run_usd: float | None = None
    scopes: dict[str, Spent] = field(default_factory=dict)

    def _scope(self, scope: str) -> Spent:
        return self.scopes.setdefault(scope, Spent(cost_usd=self._unit_cost(0, 0)))

    def _unit_cost(self, tokens_in: int, tokens_out: int) -> float | None:
        if self.local:
            return 0.0
        known = price(self.model)
        return None if known is None else (tokens_in * known[0] + tokens_out * known[1]) / 1e6

    def total(self, prefix: str = "") -> Spent:
        out = Spent()
        for name, spent in self.scopes.items():
            if not prefix or name == prefix or name.startswith(prefix + ":"):
                out.add(spent)
        return out

    def before_call(self, scope: str) -> None:
        """Refuse a call when the run's or the stage's budget is spent."""
        run = self.total()
        stage = scope.split(":", 1)[0]
        if self.run_tokens is not None and run.tokens >= self.run_tokens:
            raise BudgetExceeded(f"the run's token budget ({self.run_tokens}) is spent ({run.tokens} tokens); "
                                 "stopping the agents with what was done so far (--llm-run-tokens)")
        if self.stage_tokens is not None and self.total(stage).tokens >= self.stage_tokens:
            raise BudgetExceeded(f"the {stage} stage's token budget ({self.stage_tokens}) is spent; stopping it "
                                 "with what was done so far (--llm-stage-tokens)")
        if self.run_usd is not None and run.cost_usd is not None and run.cost_usd >= self.run_usd:
            raise BudgetExceeded(f"the run's budget of {self.run_usd} USD is spent ({run.cost_usd:.4f} USD); "
                                 "stopping the agents with what was done so far (--llm-run-usd)")

    def charge(self, scope: str, tokens_in: int, tokens_out: int) -> None:
        s = self._scope(scope)
        s.calls += 1
        s.input_tokens += tokens_in
        s.output_tokens += tokens_out
        cost = self._unit_cost(tokens_in, tokens_out)
        s.cost_usd = None if s.cost_usd is None or cost is None else s.cost_usd + cost

    def hit(self, scope: str) -> None:
        self._scope(scope).cache_hits += 1

    def failed(self, scope: str) -> None:
        self._scope(scope).failures += 1

    def to_dict(self) -> dict:
        stages: dict[str, Spent] = {}
        for name, spent in self.scopes.items():
            stages.setdefault(name.split(":", 1)[0], Spent()).add(spent)
        return {"total": self.total().to_dict(), "stages": {k: v.to_dict() for k, v in stages.items()},
                "scopes": {k: v.to_dict() for k, v in self.scopes.items()},
                "budget": {"run_tokens": self.run_tokens, "stage_tokens": self.stage_tokens, "run_usd": self.run_usd},
                "price_known": self.local or price(self.model) is not None}
