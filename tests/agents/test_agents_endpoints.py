"""The agents against a real HTTP server on 127.0.0.1 that misbehaves (``fake_endpoint.py``), through the real
``openai`` SDK: an answer cut by max_tokens, an endpoint that hangs, one that returns HTML, one that returns 500.
Each gives one clear warning line and a finished run on the deterministic path. Keys come only from the
environment and never reach a warning, agents.json, the log, the report or the response cache."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from fake_endpoint import FakeEndpoint

pytest.importorskip("openai", reason="the [llm] extra is not installed (pip install 'nerfify-ns[llm]')")

ROOT = Path(__file__).resolve().parents[2]
EXAMPLE = ROOT / "examples" / "gridlite_paper.md"
CANARY = "sk-nerfify-canary-7f3a9c1e5b"


@pytest.fixture(scope="module")
def deterministic():
    from nerfify_ns.pipeline import PaperOptions, run_paper

    return run_paper(EXAMPLE, options=PaperOptions(dry_run=True)).plan


def agents_for(url: str, tmp_path: Path, **settings):
    from nerfify_ns.agents import Agents, LLMConfig

    config = LLMConfig.parse("openai:fake-model", url, cache=tmp_path / "cache.sqlite",
                             **{"timeout": 1.0, "retries": 1, "backoff": 0.05, **settings})
    return Agents(config)


@pytest.mark.parametrize("mode, needle", [
    ("length", "was cut at max_tokens=64 (finish reason 'length')"),
    ("hang", "did not answer within 1 s (2 tries)"),
    ("html", "is not a chat completion: '<!DOCTYPE html>"),
    ("500", "answered HTTP 500"),
])
def test_a_failing_endpoint_is_one_warning_and_the_deterministic_plan(mode, needle, deterministic, tmp_path):
    from nerfify_ns.pipeline import PaperOptions, run_paper

    with FakeEndpoint(mode, hang_s=3.0) as endpoint:
        agents = agents_for(endpoint.url, tmp_path, max_tokens=64)
        result = run_paper(EXAMPLE, options=PaperOptions(dry_run=True, agents=agents))
    assert len(agents.warnings) == 1, agents.warnings
    line = agents.warnings[0]
    assert "\n" not in line and needle in line and line.startswith("llm planner:"), line
    assert line.endswith("using the deterministic plan")
    assert result.plan == deterministic  # the run finished on the deterministic path
    tries = 1 if mode == "length" else 2  # a cut answer is not retried: the same request would be cut again
    assert len(endpoint.requests) == tries


def test_the_key_is_sent_but_never_written(tmp_path, monkeypatch):
    """The key goes to the endpoint (the Authorization header) and nowhere else: not in warnings, agents.json,
    nerfify.log, the report, plan.yaml or the response cache."""
    from nerfify_ns.pipeline import PaperOptions, run_paper

    monkeypatch.setenv("OPENAI_API_KEY", CANARY)
    model_plan = yaml.safe_load((ROOT / "method_configs" / "nerfacto.yaml").read_text())
    with FakeEndpoint("ok", answer=json.dumps(model_plan)) as endpoint:
        agents = agents_for(endpoint.url, tmp_path)
        out = tmp_path / "run"
        run_paper(EXAMPLE, out, options=PaperOptions(until="plan", agents=agents))
    headers = {k.lower(): v for k, v in endpoint.requests[0]["headers"].items()}
    assert headers.get("authorization") == f"Bearer {CANARY}"
    written = [p for p in out.rglob("*") if p.is_file()] + [tmp_path / "cache.sqlite"]
    assert (out / "agents.json").is_file() and (out / "report.html").is_file()
    for path in written:
        assert CANARY.encode() not in path.read_bytes(), path
    assert not any(CANARY in w for w in agents.warnings)
    data = json.loads((out / "agents.json").read_text())
    assert data["usage"]["stages"]["planner"]["calls"] == 1 and data["endpoint"]["base_url"] == endpoint.url
    assert data["usage"]["total"]["cost_usd"] == 0.0  # an endpoint on a loopback address costs no money
    report = json.loads((out / "report.json").read_text())
    assert report["sections"]["agents"]["total"]["calls"] == data["usage"]["total"]["calls"] >= 1


def test_rerun_with_the_cache_makes_no_calls(tmp_path, deterministic):
    """The response cache is keyed by backend, model, messages, constraint and parameters: a rerun (another
    process, another port) gets the same answer and the same plan without any request."""
    from nerfify_ns.pipeline import PaperOptions, run_paper

    model_plan = yaml.safe_load((ROOT / "method_configs" / "nerfacto.yaml").read_text())
    with FakeEndpoint("ok", answer=json.dumps(model_plan)) as first:
        agents = agents_for(first.url, tmp_path)
        plan1 = run_paper(EXAMPLE, options=PaperOptions(dry_run=True, agents=agents)).plan
    assert len(first.requests) == 1 and agents.ledger.total().calls == 1
    with FakeEndpoint("500") as second:  # it would fail if it were asked
        again = agents_for(second.url, tmp_path)
        plan2 = run_paper(EXAMPLE, options=PaperOptions(dry_run=True, agents=again)).plan
    assert second.requests == [] and again.ledger.total().cache_hits == 1 and again.ledger.total().calls == 0
    assert plan1 == plan2 and not again.warnings


def test_cli_flags_and_bad_settings(tmp_path):
    """--llm on ns-nerfify: a failing endpoint is one yellow warning line, and the run finishes (exit 0)."""
    cli = Path(sys.executable).with_name("ns-nerfify")
    env = {k: v for k, v in __import__("os").environ.items() if k not in ("OPENAI_API_KEY",)}
    env["NERFIFY_LLM_CACHE"] = str(tmp_path / "cache.sqlite")
    with FakeEndpoint("html") as endpoint:
        done = subprocess.run([str(cli), str(EXAMPLE), "--dry-run", "--llm", "openai:fake", "--llm-base-url",
                               endpoint.url, "--llm-retries", "0"], capture_output=True, text=True, env=env,
                              timeout=300, cwd=tmp_path)
    assert done.returncode == 0, done.stdout + done.stderr
    warnings = [line for line in done.stdout.splitlines() if line.startswith("warning")]
    assert len(warnings) == 1 and "not a chat completion" in warnings[0], done.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cache.sqlite"]  # a dry run writes nothing else


def test_bad_llm_settings_are_one_error_line(tmp_path, monkeypatch, capsys):
    """A malformed --llm, a missing key, a bad base URL: one error line naming the problem, exit 2, nothing
    written (checked before the paper is read)."""
    from nerfify_ns.cli import _run

    monkeypatch.delenv("OPENAI_API_KEY", raising=False)
    monkeypatch.setenv("NERFIFY_LLM_CACHE", str(tmp_path / "cache.sqlite"))
    monkeypatch.chdir(tmp_path)
    for args, needle in ((["--llm", "gpt4"], "expected BACKEND:MODEL"),
                         (["--llm", "openai:gpt-4o-mini"], "needs a key in $OPENAI_API_KEY"),
                         (["--llm", "llamacpp:smol", "--llm-base-url", "127.0.0.1:8080"], "expected http://"),
                         (["--llm", "ollama:llama3", "--llm-timeout", "0"], "--llm-timeout must be positive")):
        assert _run(["paper", str(EXAMPLE), *args]) == 2
        lines = [line for line in capsys.readouterr().out.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], lines
    assert list(tmp_path.iterdir()) == []  # nothing written (not even the cache)


def test_anthropic_sdk_forced_tool_over_http(tmp_path, deterministic):
    """The anthropic SDK against the same real server: the schema goes as a forced tool, the tool's input is the
    answer; its stop reason max_tokens is a cut answer."""
    pytest.importorskip("anthropic", reason="the [llm] extra is not installed")
    from nerfify_ns.agents import Agents, LLMConfig
    from nerfify_ns.pipeline import PaperOptions, run_paper

    model_plan = yaml.safe_load((ROOT / "method_configs" / "nerfacto.yaml").read_text())
    with FakeEndpoint("ok", answer=json.dumps(model_plan)) as endpoint:
        config = LLMConfig.parse("anthropic:claude-test", endpoint.url, cache=tmp_path / "c.sqlite", timeout=5.0)
        agents = Agents(config)
        run_paper(EXAMPLE, options=PaperOptions(dry_run=True, agents=agents))
    sent = endpoint.requests[0]
    assert sent["path"].endswith("/messages") and sent["json"]["tool_choice"] == {"type": "tool", "name": "plan"}
    assert sent["json"]["tools"][0]["input_schema"]["type"] == "object" and sent["json"]["system"]
    assert agents.planner["used_model"] and not agents.warnings
    with FakeEndpoint("length", answer=json.dumps(model_plan)) as endpoint:
        cut = Agents(config.with_(base_url=endpoint.url, cache=None, max_tokens=32))
        assert run_paper(EXAMPLE, options=PaperOptions(dry_run=True, agents=cut)).plan == deterministic
    assert len(cut.warnings) == 1 and "cut at max_tokens=32" in cut.warnings[0]


@pytest.mark.slow
def test_a_killed_run_resumes_from_the_cache(tmp_path):
    """A crash (SIGKILL of ns-nerfify while the endpoint is still answering its second request) loses only the
    unanswered request: the first answer was committed to the cache as it arrived. The rerun replays it without a
    request, asks the second request exactly as the killed run did (the re-ask carrying the first answer's
    problems), and finishes; the killed run left no output folder behind."""
    import os
    import signal
    import time

    cli = Path(sys.executable).with_name("ns-nerfify")
    env = {k: v for k, v in os.environ.items() if k != "OPENAI_API_KEY"}
    env["NERFIFY_LLM_CACHE"] = str(tmp_path / "cache.sqlite")
    out = tmp_path / "run"
    args = [str(cli), str(EXAMPLE), "--until", "plan", "--out", str(out), "--llm", "openai:fake",
            "--llm-timeout", "300", "--llm-retries", "2"]
    invalid = json.dumps({"base": "nerfacto", "fields": {"not": "a derivation"}})
    valid = json.dumps(yaml.safe_load((ROOT / "method_configs" / "nerfacto.yaml").read_text()))
    with FakeEndpoint(sequence=[("ok", invalid), ("hang", "")], hang_s=120) as first:
        proc = subprocess.Popen([*args, "--llm-base-url", first.url], env=env, cwd=tmp_path, start_new_session=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
        deadline = time.monotonic() + 240
        while len(first.requests) < 2 and proc.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert len(first.requests) == 2, (proc.poll(), proc.stdout.read().decode() if proc.poll() is not None else "")
        os.killpg(proc.pid, signal.SIGKILL)  # a crash: no handler runs, nothing is cleaned up
        proc.wait(timeout=30)
        proc.stdout.close()
    assert proc.returncode == -signal.SIGKILL and not out.exists()
    with FakeEndpoint(sequence=[("ok", valid), ("500", "")]) as second:
        done = subprocess.run([*args, "--llm-base-url", second.url], env=env, cwd=tmp_path, capture_output=True,
                              text=True, timeout=300)
    assert done.returncode == 0, done.stdout + done.stderr
    asked = [r["json"]["messages"] for r in second.requests]  # (the coder's requests, answered 500, follow)
    assert first.requests[0]["json"]["messages"] not in asked  # the first answer came from the cache
    resumed = asked[0]
    assert resumed == first.requests[1]["json"]["messages"] and "rejected" in resumed[-1]["content"]
    usage = json.loads((out / "agents.json").read_text())["usage"]["stages"]["planner"]
    assert usage["calls"] == 1 and usage["cache_hits"] == 1
