"""A real HTTP server on 127.0.0.1 that speaks (or fails to speak) OpenAI's chat-completions API, for the agents'
failure-mode tests: the SDK, its HTTP client and our error handling all run for real; only the model is fixed.

Modes: ``ok`` (a chat completion whose content is ``answer``; on ``/messages``, Anthropic's message with a
``tool_use`` block whose input is ``answer``), ``length`` (the same, cut: finish reason
``length``), ``html`` (200 with an HTML page), ``500`` (an internal server error), ``hang`` (accepts the request
and answers nothing for ``hang_s`` seconds). ``sequence`` scripts the requests one by one: a list of
``(mode, answer)``, the n-th request gets the n-th pair (the last pair repeats). Every request is kept (path,
headers, JSON body), bounded in count.
"""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Sequence
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer


class FakeEndpoint:
    MAX_REQUESTS = 200

    def __init__(self, mode: str = "ok", answer: str = "{}", hang_s: float = 5.0,
                 sequence: Sequence[tuple[str, str]] | None = None) -> None:
        self.mode, self.answer, self.hang_s = mode, answer, hang_s
        self.sequence = list(sequence or [])
        self.requests: list[dict] = []
        endpoint = self

        class Handler(BaseHTTPRequestHandler):
            def log_message(self, *args):  # quiet
                pass

            def do_POST(self):  # noqa: N802
                length = int(self.headers.get("Content-Length") or 0)
                body = self.rfile.read(length)
                index = len(endpoint.requests)
                if index < endpoint.MAX_REQUESTS:
                    endpoint.requests.append({"path": self.path, "headers": dict(self.headers),
                                              "json": json.loads(body or b"{}")})
                endpoint.respond(self, *endpoint.sequence[min(index, len(endpoint.sequence) - 1)]
                                 if endpoint.sequence else (endpoint.mode, endpoint.answer))

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.server.daemon_threads = True
        self.thread = threading.Thread(target=self.server.serve_forever, daemon=True)

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.server.server_address[1]}/v1"

    def _send(self, handler, status: int, body: bytes, ctype: str) -> None:
        handler.send_response(status)
        handler.send_header("Content-Type", ctype)
        handler.send_header("Content-Length", str(len(body)))
        handler.end_headers()
        handler.wfile.write(body)

    def respond(self, handler, mode: str, answer: str) -> None:
        if mode == "hang":
            time.sleep(self.hang_s)  # bounded: the server never waits forever
            return
        if mode == "html":
            return self._send(handler, 200, b"<!DOCTYPE html><html><body><h1>Welcome to nginx!</h1></body></html>",
                              "text/html")
        if mode == "500":
            return self._send(handler, 500, b'{"error": {"message": "internal error", "type": "server_error"}}',
                              "application/json")
        if handler.path.endswith("/messages"):  # Anthropic's messages API: the answer as a forced tool's input
            body = {"id": "msg_1", "type": "message", "role": "assistant", "model": "fake",
                    "content": [{"type": "tool_use", "id": "toolu_1", "name": "plan", "input": json.loads(answer)}],
                    "stop_reason": "max_tokens" if mode == "length" else "tool_use", "stop_sequence": None,
                    "usage": {"input_tokens": 100, "output_tokens": 20}}
            return self._send(handler, 200, json.dumps(body).encode(), "application/json")
        finish = "length" if mode == "length" else "stop"
        text = answer[:20] if mode == "length" else answer
        body = {"id": "chatcmpl-1", "object": "chat.completion", "created": 0, "model": "fake",
                "choices": [{"index": 0, "message": {"role": "assistant", "content": text},
                             "finish_reason": finish}],
                "usage": {"prompt_tokens": 100, "completion_tokens": 20, "total_tokens": 120}}
        self._send(handler, 200, json.dumps(body).encode(), "application/json")

    def __enter__(self) -> FakeEndpoint:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.server.shutdown()
        self.server.server_close()
