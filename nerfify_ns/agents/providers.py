"""One small interface of ours over the model SDKs: ``Provider.complete(Request) -> Response``.

* :class:`OpenAIProvider`: the official ``openai`` SDK, for OpenAI and every OpenAI-compatible server (vLLM,
  Ollama's ``/v1``, llama.cpp's server, LM Studio) through a base URL.
* :class:`AnthropicProvider`: the official ``anthropic`` SDK.
* :class:`ScriptedProvider`: a deterministic model replaying fixed answers (tests, dry runs of the orchestration).

The SDKs are imported only when a provider is built (``pip install nerfify-ns[llm]``); their own retries are off
(the client retries, bounded, with backoff). How the constraint reaches each backend is a table
(:data:`SHAPES`, keyed by the capability table's ``structured`` mode), not a chain of conditions. Errors become
:class:`ProviderError` with a one-line message (the key never appears in one: it is not in the request we
build, and the SDK's messages do not carry headers).

Every request the SDKs send goes through our network layer (:class:`_DeadlineBackend` under the SDK's own HTTP
client): ``--llm-timeout`` is the deadline of the whole request (connecting, sending, the headers and the body,
however slowly they drip), every read waits at most what is left of it; the bytes received are counted and a
response over ``max_body`` bytes is refused while it arrives; a compressed body (we ask for none) is refused
rather than inflated. The scripted answers file is read within the bounds of :mod:`nerfify_ns.safeio`.
"""

from __future__ import annotations

import contextlib
import importlib
import json
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from nerfify_ns.agents.config import LLMConfig
from nerfify_ns.agents.errors import LLMSetupError, ProviderError


@dataclass
class Request:
    """What is sent: messages (``{role, content}``; content a string or a list of ``{type: text|image}`` parts,
    an image as ``{type: image, png_base64}``), the constraint (JSON Schema and/or GBNF), sampling settings."""

    messages: list[dict]
    schema: dict | None = None
    schema_name: str = "answer"
    grammar: str | None = None
    max_tokens: int = 1024
    temperature: float = 0.0
    seed: int | None = None
    stage: str = ""
    """Which agent asks (not sent; the scripted model answers per stage)."""

    def key_data(self, config: LLMConfig) -> dict:
        """What the response cache is keyed by: backend, model, messages, constraint, parameters."""
        return {"backend": config.backend, "model": config.model, "messages": self.messages, "schema": self.schema,
                "grammar": self.grammar, "max_tokens": self.max_tokens, "temperature": self.temperature,
                "seed": self.seed, "structured": config.info.structured if config.constrained else "none"}


@dataclass
class Response:
    """What came back: the text (a tool call's input as JSON), why the model stopped, the tokens it cost."""

    text: str
    finish: str
    input_tokens: int = 0
    output_tokens: int = 0
    model: str = ""
    cached: bool = False


class Provider:
    """The interface: one request, one response (or a :class:`ProviderError`)."""

    name = "provider"

    def complete(self, request: Request) -> Response:  # pragma: no cover - interface
        raise NotImplementedError


# ------------------------------------------------------------------------------------------ shapes
def _openai_json_schema(req: Request, strict: bool) -> dict:
    return {"response_format": {"type": "json_schema", "json_schema": {
        "name": req.schema_name, "schema": req.schema, "strict": strict}}} if req.schema else {}


def _vllm(req: Request, strict: bool) -> dict:
    if req.grammar:
        return {"extra_body": {"structured_outputs": {"grammar": req.grammar}}}
    return {"extra_body": {"structured_outputs": {"json": req.schema}}} if req.schema else {}


def _ollama(req: Request, strict: bool) -> dict:
    if not req.schema:
        return {}
    return {**_openai_json_schema(req, False), "extra_body": {"format": req.schema}}


def _llamacpp_json_schema(req: Request, strict: bool) -> dict:
    return {"response_format": {"type": "json_object", "schema": req.schema}} if req.schema else {}


def _llamacpp_gbnf(req: Request, strict: bool) -> dict:
    if req.grammar:
        return {"extra_body": {"grammar": req.grammar}}
    return _llamacpp_json_schema(req, strict)


SHAPES: dict[str, Callable[[Request, bool], dict]] = {
    "openai_json_schema": _openai_json_schema,
    "vllm_structured": _vllm,
    "ollama_format": _ollama,
    "llamacpp_json_schema": _llamacpp_json_schema,
    "llamacpp_gbnf": _llamacpp_gbnf,
    "none": lambda req, strict: {},
}
"""How the constraint is put into an OpenAI-SDK request, per structured mode of the capability table."""


def _openai_messages(messages: list[dict]) -> list[dict]:
    out = []
    for m in messages:
        content = m["content"]
        if isinstance(content, list):
            content = [{"type": "text", "text": p["text"]} if p["type"] == "text" else
                       {"type": "image_url", "image_url": {"url": f"data:image/png;base64,{p['png_base64']}"}}
                       for p in content]
        out.append({"role": m["role"], "content": content})
    return out


def _first_line(text: Any, limit: int = 200) -> str:
    line = " ".join(str(text).split())
    return line[:limit] + ("..." if len(line) > limit else "")


def _import(module: str):
    try:
        return __import__(module)
    except ImportError:
        raise LLMSetupError(f"the '{module}' package is not installed: pip install 'nerfify-ns[llm]'") from None



# ------------------------------------------------------------------------------------------ deadline and size
class BodyTooLarge(Exception):
    """A response grew past the call's byte limit while it arrived (raised inside the SDK's HTTP client)."""


class _CallLimits(threading.local):
    deadline: float | None = None
    budget: int | None = None
    received: int = 0


_limits = _CallLimits()


@contextlib.contextmanager
def call_limits(seconds: float, max_bytes: int) -> Iterator[None]:
    """Bound every network read and write of this thread's requests inside the block: a total deadline of
    ``seconds`` and at most ``max_bytes`` received (headers included)."""
    _limits.deadline, _limits.budget, _limits.received = time.monotonic() + seconds, max_bytes, 0
    try:
        yield
    finally:
        _limits.deadline, _limits.budget, _limits.received = None, None, 0


def _left(timeout: float | None, error: type) -> float | None:
    """The wait allowed now: the smaller of ``timeout`` and what is left of the call's deadline (``error``
    raised once it passed)."""
    if _limits.deadline is None:
        return timeout
    left = _limits.deadline - time.monotonic()
    if left <= 0:
        raise error("the request's total deadline passed")
    return left if timeout is None else min(timeout, left)


def _limited_backend(httpcore: Any) -> Any:
    """A network backend of ``httpcore`` (httpcore or httpcore2, whichever the SDK's client uses) that bounds every
    read and write by the call's deadline and counts the bytes received (:func:`call_limits`)."""

    class Stream(httpcore.NetworkStream):
        def __init__(self, inner: Any) -> None:
            self.inner = inner

        def read(self, max_bytes: int, timeout: float | None = None) -> bytes:
            data = self.inner.read(max_bytes, _left(timeout, httpcore.ReadTimeout))
            if _limits.budget is not None:
                _limits.received += len(data)
                if _limits.received > _limits.budget:
                    raise BodyTooLarge(f"the response is over {_limits.budget} bytes")
            return data

        def write(self, buffer: bytes, timeout: float | None = None) -> None:
            self.inner.write(buffer, _left(timeout, httpcore.WriteTimeout))

        def close(self) -> None:
            self.inner.close()

        def start_tls(self, ssl_context: Any, server_hostname: str | None = None,
                      timeout: float | None = None) -> Any:
            return Stream(self.inner.start_tls(ssl_context, server_hostname, _left(timeout, httpcore.ConnectTimeout)))

        def get_extra_info(self, info: str) -> Any:
            return self.inner.get_extra_info(info)

    class Backend(httpcore.NetworkBackend):
        def __init__(self, inner: Any) -> None:
            self.inner = inner

        def connect_tcp(self, host: str, port: int, timeout: float | None = None, local_address: Any = None,
                        socket_options: Any = None) -> Any:
            return Stream(self.inner.connect_tcp(host, port, _left(timeout, httpcore.ConnectTimeout), local_address,
                                                 socket_options))

        def connect_unix_socket(self, path: str, timeout: float | None = None, socket_options: Any = None) -> Any:
            return Stream(self.inner.connect_unix_socket(path, _left(timeout, httpcore.ConnectTimeout),
                                                         socket_options))

        def sleep(self, seconds: float) -> None:
            self.inner.sleep(seconds)

    return Backend


def limited_http_client(sdk: Any, timeout: float) -> Any:
    """An HTTP client for ``sdk`` (the openai or anthropic module) whose connections go through the limited
    backend, that asks for an uncompressed body and refuses a compressed one (never inflated)."""
    base = importlib.import_module(f"{sdk.__name__}._base_client")
    httpx = getattr(base, "httpx2", None) or base.httpx
    httpcore = importlib.import_module("httpcore2" if httpx.__name__ == "httpx2" else "httpcore")

    class Transport(httpx.HTTPTransport):
        def __init__(self) -> None:
            super().__init__()
            pool = getattr(self, "_pool", None)
            inner = getattr(pool, "_network_backend", None)
            if inner is None:  # a client layout we do not know: refuse rather than run unbounded
                raise LLMSetupError(f"cannot bound the requests of this {httpx.__name__} version; "
                                    "pip install 'nerfify-ns[llm]'")
            pool._network_backend = _limited_backend(httpcore)(inner)

        def handle_request(self, request: Any) -> Any:
            request.headers["Accept-Encoding"] = "identity"
            response = super().handle_request(request)
            encoding = response.headers.get("Content-Encoding", "identity").strip().lower()
            if encoding not in ("", "identity"):
                response.close()
                raise BodyTooLarge(f"the response is compressed ({encoding}) although none was asked for; it is "
                                   "not inflated")
            return response

    return httpx.Client(transport=Transport(), timeout=timeout, follow_redirects=False)


def _cause(exc: BaseException, kind: type) -> BaseException | None:
    seen = 0
    while exc is not None and seen < 20:
        if isinstance(exc, kind):
            return exc
        exc = exc.__cause__ or exc.__context__
        seen += 1
    return None


def _sdk_call(sdk: Any, create: Callable[..., Any], kwargs: dict, where: str, timeout: float,
              max_body: int = 32 << 20) -> Any:
    """``create(**kwargs)`` within the call's limits (:func:`call_limits`), with the SDK's errors as
    :class:`ProviderError` (the openai and anthropic SDKs name their errors alike): a timeout (the whole call's),
    a body over the limit, no connection, an HTTP status, a body that is not the API's JSON."""
    try:
        with call_limits(timeout, max_body):
            return create(**kwargs)
    except BodyTooLarge as exc:
        raise ProviderError("too-large", f"{where}: {exc}; refused", retry=False) from None
    except sdk.APITimeoutError:
        raise ProviderError("timeout", f"{where} did not answer within {timeout:g} s", retry=True) from None
    except sdk.APIConnectionError as exc:
        large = _cause(exc, BodyTooLarge)
        if large is not None:
            raise ProviderError("too-large", f"{where}: {large}; refused", retry=False) from None
        raise ProviderError("connection", f"cannot reach {where}: {_first_line(exc.__cause__ or exc)}",
                            retry=True) from None
    except sdk.APIStatusError as exc:
        raise _status_error(exc, where) from None
    except sdk.APIError as exc:
        large = _cause(exc, BodyTooLarge)
        if large is not None:
            raise ProviderError("too-large", f"{where}: {large}; refused", retry=False) from None
        raise ProviderError("not-json", f"{where} did not answer with the API's JSON: {_first_line(exc)}",
                            retry=True) from None

def _status_error(exc: Any, where: str) -> ProviderError:
    status = getattr(exc, "status_code", None) or getattr(getattr(exc, "response", None), "status_code", None)
    body = getattr(getattr(exc, "response", None), "text", "") or str(exc)
    retry = status is None or status >= 500 or status in (408, 409, 429)
    return ProviderError("http", f"{where} answered HTTP {status}: {_first_line(body, 120)}", retry=retry)


class OpenAIProvider(Provider):
    """The ``openai`` SDK's chat completions, shaped per backend (:data:`SHAPES`)."""

    name = "openai"

    def __init__(self, config: LLMConfig) -> None:
        openai = _import("openai")
        self.openai, self.config = openai, config
        self.client = openai.OpenAI(api_key=config.api_key(), base_url=config.endpoint, timeout=config.timeout,
                                    max_retries=0, http_client=limited_http_client(openai, config.timeout))
        self.where = config.endpoint or "the OpenAI API"

    def complete(self, request: Request) -> Response:
        info, openai = self.config.info, self.openai
        kwargs: dict[str, Any] = {"model": self.config.model, "messages": _openai_messages(request.messages),
                                  "max_tokens": request.max_tokens, "temperature": request.temperature}
        if info.seed and request.seed is not None:
            kwargs["seed"] = request.seed
        mode = info.structured if self.config.constrained else "none"
        kwargs.update(SHAPES[mode](request, info.strict_schema))
        raw = _sdk_call(openai, self.client.chat.completions.create, kwargs, self.where, self.config.timeout,
                        self.config.max_body)
        choices = getattr(raw, "choices", None)
        if not choices:  # the SDK hands back a string when the body is not JSON (an HTML page, a proxy's error)
            raise ProviderError("not-json", f"{self.where} answered with something that is not a chat completion: "
                                f"{_first_line(raw, 80)!r}", retry=True)
        choice = choices[0]
        usage = getattr(raw, "usage", None)
        return Response(text=choice.message.content or "", finish=str(choice.finish_reason or "stop"),
                        input_tokens=int(getattr(usage, "prompt_tokens", 0) or 0),
                        output_tokens=int(getattr(usage, "completion_tokens", 0) or 0),
                        model=str(getattr(raw, "model", "") or self.config.model))


class AnthropicProvider(Provider):
    """The ``anthropic`` SDK's messages; the schema as a forced tool (its input is the answer)."""

    name = "anthropic"
    FINISH = {"max_tokens": "length", "end_turn": "stop", "tool_use": "stop", "stop_sequence": "stop",
              "refusal": "refused"}

    def __init__(self, config: LLMConfig) -> None:
        anthropic = _import("anthropic")
        self.anthropic, self.config = anthropic, config
        self.client = anthropic.Anthropic(api_key=config.api_key(), base_url=config.endpoint,
                                          timeout=config.timeout, max_retries=0,
                                          http_client=limited_http_client(anthropic, config.timeout))
        self.where = config.endpoint or "the Anthropic API"

    @staticmethod
    def _messages(messages: list[dict]) -> tuple:
        system = "\n\n".join(m["content"] for m in messages if m["role"] == "system")
        out = []
        for m in messages:
            if m["role"] == "system":
                continue
            content = m["content"]
            if isinstance(content, list):
                content = [{"type": "text", "text": p["text"]} if p["type"] == "text" else
                           {"type": "image", "source": {"type": "base64", "media_type": "image/png",
                                                        "data": p["png_base64"]}} for p in content]
            out.append({"role": m["role"], "content": content})
        return system, out

    def complete(self, request: Request) -> Response:
        anthropic = self.anthropic
        system, messages = self._messages(request.messages)
        # no temperature: the SDK's messages API (anthropic 2.x) takes none; its sampling is the model's
        kwargs: dict[str, Any] = {"model": self.config.model, "messages": messages, "max_tokens": request.max_tokens}
        if system:
            kwargs["system"] = system
        if request.schema and self.config.constrained:
            kwargs["tools"] = [{"name": request.schema_name, "description": "Give the answer.",
                                "input_schema": request.schema}]
            kwargs["tool_choice"] = {"type": "tool", "name": request.schema_name}
        raw = _sdk_call(anthropic, self.client.messages.create, kwargs, self.where, self.config.timeout,
                        self.config.max_body)
        blocks = getattr(raw, "content", None)
        if blocks is None:
            raise ProviderError("not-json", f"{self.where} answered with something that is not a message: "
                                f"{_first_line(raw, 80)!r}", retry=True)
        tool = next((b for b in blocks if getattr(b, "type", "") == "tool_use"), None)
        text = json.dumps(tool.input) if tool is not None else "".join(getattr(b, "text", "") for b in blocks)
        usage = getattr(raw, "usage", None)
        return Response(text=text, finish=self.FINISH.get(str(raw.stop_reason), str(raw.stop_reason)),
                        input_tokens=int(getattr(usage, "input_tokens", 0) or 0),
                        output_tokens=int(getattr(usage, "output_tokens", 0) or 0), model=str(raw.model))


# ------------------------------------------------------------------------------------------ scripted
Answer = str | dict | Callable[[Request], str | dict]
MAX_SCRIPT = 8 << 20
"""Bytes of a scripted answers file."""
MAX_SCRIPT_NODES = 200_000
"""Nodes a scripted answers file may expand to (aliases counted as what they stand for)."""


class ScriptedProvider(Provider):
    """A model that replays fixed answers, per stage in order (``{"planner": [...], "coder": [...]}``), or one
    list for every stage. An answer is the text, or ``{text, finish}``, or ``{error: KIND, message}`` (a
    :class:`ProviderError`), or a function of the request. Tokens are counted as characters / 4. Every request
    is kept in ``requests`` (what a test asserts was sent)."""

    name = "scripted"

    def __init__(self, answers: list[Answer] | dict[str, list[Answer]]) -> None:
        self.answers = answers if isinstance(answers, dict) else {"*": list(answers)}
        self.used: dict[str, int] = {}
        self.requests: list[Request] = []

    @classmethod
    def from_file(cls, path: str | Path) -> ScriptedProvider:
        from nerfify_ns import safeio

        path = Path(path)
        try:
            data = safeio.load_yaml(path, MAX_SCRIPT, what="the file", max_nodes=MAX_SCRIPT_NODES)
        except safeio.ReadRefused as exc:
            raise LLMSetupError(f"scripted answers {path}: cannot read it ({_first_line(exc, 200)})") from None
        if not isinstance(data, list | dict):
            raise LLMSetupError(f"scripted answers {path}: expected a list, or a mapping stage -> list")
        return cls(data)

    def complete(self, request: Request) -> Response:
        self.requests.append(request)
        stage = request.stage.split(":", 1)[0]
        key = stage if stage in self.answers else "*"
        queue = self.answers.get(key) or []
        n = self.used.get(key, 0)
        if n >= len(queue):
            raise ProviderError("exhausted", f"the scripted model has no answer left for {stage or 'this stage'} "
                                f"(it had {len(queue)})")
        self.used[key] = n + 1
        answer = queue[n]
        if callable(answer):
            answer = answer(request)
        if isinstance(answer, dict) and "error" in answer:
            raise ProviderError(str(answer["error"]), str(answer.get("message", answer["error"])),
                                retry=bool(answer.get("retry", False)))
        if isinstance(answer, dict) and "text" not in answer:
            answer = {"text": json.dumps(answer)}
        if isinstance(answer, str):
            answer = {"text": answer}
        text = str(answer["text"])
        prompt = sum(len(str(m["content"])) for m in request.messages)
        return Response(text=text, finish=str(answer.get("finish", "stop")), input_tokens=prompt // 4 + 1,
                        output_tokens=len(text) // 4 + 1, model="scripted")


def make_provider(config: LLMConfig) -> Provider:
    """The provider of ``config``'s backend (its SDK imported now, not before)."""
    factories: dict[str, Callable[[LLMConfig], Provider]] = {
        "openai": OpenAIProvider, "anthropic": AnthropicProvider,
        "scripted": lambda c: ScriptedProvider.from_file(c.model)}
    return factories[config.info.sdk](config)
