"""``--llm-timeout`` is the deadline of a whole request, and a response has a size limit: real servers on
127.0.0.1 that drip the body (or the headers) one byte a second, send a body larger than the limit, or a gzip
body, through the real SDKs and their HTTP clients. Each call ends within the deadline (plus a read's slack) with
one line saying why; the CLI turns it into one warning and the deterministic result stands."""

from __future__ import annotations

import gzip
import json
import os
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from nerfify_ns.agents import LLMConfig
from nerfify_ns.agents.errors import ProviderError
from nerfify_ns.agents.providers import Request, make_provider

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"
COMPLETION = json.dumps({"id": "x", "object": "chat.completion", "created": 0, "model": "m", "choices": [
    {"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": "{}"}}],
    "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2}}).encode()


class RawServer:
    """A TCP server on 127.0.0.1 (port 0) answering every request with ``respond(sock)`` in its own thread."""

    def __init__(self, respond) -> None:
        self.respond, self.stop = respond, threading.Event()
        self.sock = socket.socket()
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.listen(8)
        self.sock.settimeout(0.2)
        self.url = f"http://127.0.0.1:{self.sock.getsockname()[1]}/v1"
        threading.Thread(target=self._serve, daemon=True).start()

    def _serve(self) -> None:
        while not self.stop.is_set():
            try:
                conn, _ = self.sock.accept()
            except OSError:
                continue
            threading.Thread(target=self._one, args=(conn,), daemon=True).start()

    def _one(self, conn) -> None:
        try:
            conn.settimeout(5)
            data = b""
            while b"\r\n\r\n" not in data:
                data += conn.recv(65536)
            head, _, body = data.partition(b"\r\n\r\n")
            length = int(next((line.split(b":")[1] for line in head.split(b"\r\n")
                               if line.lower().startswith(b"content-length")), b"0"))
            while len(body) < length:
                body += conn.recv(65536)
            self.respond(conn, self.stop)
        except OSError:
            pass
        finally:
            conn.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.stop.set()
        self.sock.close()


def drip_body(conn, stop) -> None:
    conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: %d\r\n\r\n" % len(COMPLETION))
    for byte in COMPLETION:
        if stop.wait(1.0):
            return
        conn.sendall(bytes([byte]))


def drip_headers(conn, stop) -> None:
    for byte in b"HTTP/1.1 200 OK\r\nX-Slow: " + b"a" * 1000:
        if stop.wait(1.0):
            return
        conn.sendall(bytes([byte]))


def huge_body(conn, stop) -> None:
    conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nTransfer-Encoding: chunked\r\n\r\n")
    chunk = b"[" * 65536
    for _ in range(1 << 14):  # 1 GiB if nobody stops reading
        if stop.is_set():
            return
        conn.sendall(b"%x\r\n%s\r\n" % (len(chunk), chunk))


def gzip_bomb(conn, stop) -> None:
    body = gzip.compress(b" " * (64 << 20))  # 64 MB of spaces in 64 KB
    conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Encoding: gzip\r\n"
                 b"Content-Length: %d\r\n\r\n" % len(body) + body)


def ok(conn, stop) -> None:
    conn.sendall(b"HTTP/1.1 200 OK\r\nContent-Type: application/json\r\nContent-Length: %d\r\n\r\n" % len(COMPLETION)
                 + COMPLETION)


def provider(url: str, backend: str = "openai", **settings):
    config = LLMConfig.parse(f"{backend}:m", url if backend == "openai" else url.rsplit("/v1", 1)[0],
                             retries=0, **settings)
    return make_provider(config)


def ask(p) -> tuple:
    start = time.perf_counter()
    try:
        return p.complete(Request(messages=[{"role": "user", "content": "hi"}], stage="planner")), \
            time.perf_counter() - start
    except ProviderError as exc:
        return exc, time.perf_counter() - start


@pytest.mark.parametrize("respond", [drip_body, drip_headers], ids=["body", "headers"])
def test_a_dripping_endpoint_does_not_hold_a_call_past_its_timeout(respond):
    with RawServer(respond) as server:
        error, seconds = ask(provider(server.url, timeout=2.0))
    assert isinstance(error, ProviderError) and error.kind == "timeout", error
    assert "did not answer within 2 s" in str(error) and "\n" not in str(error)
    assert seconds < 3.5, seconds  # the deadline, plus a read's slack; it used to hold for the whole drip


def test_anthropic_requests_have_the_same_deadline():
    with RawServer(drip_body) as server:
        error, seconds = ask(provider(server.url, backend="anthropic", timeout=2.0))
    assert isinstance(error, ProviderError) and error.kind == "timeout" and seconds < 3.5, (error, seconds)


def test_a_body_over_the_limit_is_refused_while_it_arrives():
    with RawServer(huge_body) as server:
        error, seconds = ask(provider(server.url, timeout=60.0, max_body=4 << 20))
    assert isinstance(error, ProviderError) and error.kind == "too-large" and not error.retry, error
    assert "over 4194304 bytes" in str(error) and seconds < 20


def test_a_compressed_body_is_not_inflated():
    with RawServer(gzip_bomb) as server:
        error, _ = ask(provider(server.url, timeout=30.0))
    assert isinstance(error, ProviderError) and error.kind == "too-large" and "compressed (gzip)" in str(error)


def test_an_honest_endpoint_still_answers():
    with RawServer(ok) as server:
        response, _ = ask(provider(server.url, timeout=10.0))
    assert not isinstance(response, ProviderError), response
    assert response.text == "{}" and response.finish == "stop"


def test_the_cli_gives_one_warning_within_the_timeout(tmp_path):
    env = {**os.environ, "NERFIFY_LLM_CACHE": str(tmp_path / "cache.sqlite")}
    env.pop("OPENAI_API_KEY", None)
    cli = Path(sys.executable).with_name("ns-nerfify")
    with RawServer(drip_body) as server:
        start = time.perf_counter()
        done = subprocess.run([str(cli), str(EXAMPLE), "--dry-run", "--llm", "openai:m", "--llm-base-url",
                               server.url, "--llm-timeout", "2", "--llm-retries", "0"], capture_output=True,
                              text=True, env=env, timeout=300, cwd=tmp_path)
        seconds = time.perf_counter() - start
    assert done.returncode == 0, done.stdout + done.stderr
    warnings = [line for line in done.stdout.splitlines() if line.startswith("warning")]
    assert len(warnings) == 1 and "did not answer within 2 s" in warnings[0], done.stdout
    assert "Traceback" not in done.stdout + done.stderr
    assert seconds < 120, seconds  # the plan's own work plus one 2-s call (the drip alone would take 200 s)
