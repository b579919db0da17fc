"""One structured question to the model, done carefully: cache, budget, bounded retries with backoff, the finish
reason checked (a truncated answer is not an answer), JSON salvaged with ``json-repair``, then validated by our
own checks (the grammar's ``validate``, a schema, a contract); a rejected answer goes back to the model with the
problems, within the retry bound.

    client = Client(config, provider, cache, ledger)
    answer = client.ask("planner", messages, schema=schema, grammar=gbnf, check=lambda value: problems)
    answer.value, answer.notes, answer.response
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from nerfify_ns.agents.cache import ResponseCache, cache_key
from nerfify_ns.agents.config import LLMConfig
from nerfify_ns.agents.errors import InvalidAnswer, ProviderError
from nerfify_ns.agents.providers import Provider, Request, Response
from nerfify_ns.agents.usage import Ledger

LOG = logging.getLogger("nerfify.agents")
Check = Callable[[Any], list[str]]


@dataclass
class Answer:
    value: Any
    response: Response
    attempts: int
    notes: list[str] = field(default_factory=list)


def parse_json(text: str) -> tuple:
    """(value, notes): the text as JSON, else salvaged with json-repair (a fence, a trailing comma, a quote); a
    text with no JSON in it gives (None, [why])."""
    body = text.strip()
    if body.startswith("```"):
        body = body.strip("`")
        body = body[body.find("\n") + 1:] if "\n" in body else body
    try:
        return json.loads(body), []
    except ValueError:
        pass
    try:
        import json_repair
    except ImportError:
        return None, ["not JSON, and json-repair is not installed (pip install 'nerfify-ns[llm]')"]
    value = json_repair.loads(body)
    if value in ("", None, [], {}) and body not in ("{}", "[]"):
        return None, [f"not JSON: {body[:80]!r}"]
    return value, ["the answer was not valid JSON; salvaged with json-repair"]


class Client:
    """The agents' only way to a model (see the module docstring)."""

    def __init__(self, config: LLMConfig, provider: Provider, cache: ResponseCache, ledger: Ledger,
                 sleep: Callable[[float], None] = time.sleep) -> None:
        self.config, self.provider, self.cache, self.ledger, self.sleep = config, provider, cache, ledger, sleep

    def _call(self, scope: str, request: Request) -> Response:
        """The response to ``request``: from the cache, else from the provider (retried on transient failures,
        bounded, with doubling backoff)."""
        key = cache_key(request.key_data(self.config))
        hit = self.cache.get(key)
        if hit is not None:
            self.ledger.hit(scope)
            return hit
        last: ProviderError | None = None
        for attempt in range(self.config.retries + 1):
            self.ledger.before_call(scope)
            try:
                response = self.provider.complete(request)
            except ProviderError as exc:
                self.ledger.failed(scope)
                last = exc
                LOG.warning("llm %s: %s (try %d of %d)", scope, exc, attempt + 1, self.config.retries + 1)
                if not exc.retry or attempt == self.config.retries:
                    break
                self.sleep(self.config.backoff * 2 ** attempt)
                continue
            self.ledger.charge(scope, response.input_tokens, response.output_tokens)
            self.cache.put(key, response, self.config.backend)
            return response
        tries = f" ({self.config.retries + 1} tries)" if last is not None and last.retry and self.config.retries else ""
        raise ProviderError(last.kind, f"{last}{tries}", retry=False)

    def ask(self, scope: str, messages: list[dict], *, schema: dict | None = None, grammar: str | None = None,
            check: Check | None = None, max_tokens: int | None = None, schema_name: str = "answer",
            reask: bool = True) -> Answer:
        """A JSON answer that passes ``check`` (a list of problems; empty = accepted). A truncated answer raises
        at once (the same request would be cut again); an invalid one is re-asked with its problems, at most
        ``retries`` times, then :class:`InvalidAnswer`."""
        messages = list(messages)
        notes: list[str] = []
        problems: list[str] = []
        limit = max_tokens or self.config.max_tokens
        for attempt in range(self.config.retries + 1):
            request = Request(messages=messages, schema=schema, schema_name=schema_name,
                              grammar=grammar if self.config.constrained else None, max_tokens=limit,
                              temperature=self.config.temperature,
                              seed=self.config.seed if self.config.info.seed else None, stage=scope)
            response = self._call(scope, request)
            if response.finish == "length":
                raise ProviderError("truncated", f"the answer was cut at max_tokens={limit} (finish reason "
                                    "'length'): a truncated answer is not an answer; raise --llm-max-tokens")
            if response.finish not in ("stop", "tool_calls", "eos"):
                raise ProviderError("refused", f"the model stopped with finish reason {response.finish!r}")
            value, parse_notes = parse_json(response.text)
            notes += parse_notes
            problems = parse_notes if value is None else (check(value) if check else [])
            if not problems:
                return Answer(value, response, attempt + 1, notes)
            LOG.warning("llm %s: answer rejected: %s", scope, "; ".join(problems[:3]))
            if not reask:
                break
            messages = messages + [{"role": "assistant", "content": response.text},
                                   {"role": "user", "content": "That answer was rejected:\n- " + "\n- ".join(
                                       problems[:10]) + "\nAnswer again, fixing these problems."}]
        first = problems[0] if problems else "?"
        raise InvalidAnswer(f"the model's answer was rejected after {attempt + 1} tries: {first}"
                            + (f" (+{len(problems) - 1} more)" if len(problems) > 1 else ""), problems)
