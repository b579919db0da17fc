"""Fast checks of the ladder's parts: plugin loading, AST rung, sandbox, fixers, report."""

import ast
import json
import sys

import pytest

from nerfify_ns.runtime.sandbox import available_modes, isolation_available, run_sandboxed
from nerfify_ns.verify import Diagnosis, LadderReport, NotAPluginError, RungResult
from nerfify_ns.verify.plugin import load_plugin
from nerfify_ns.verify.repair import ExpGuardFixer, OptimizerGroupFixer
from nerfify_ns.verify.rungs import static_ast
from nerfify_ns.verify.static import ast_checks


def test_not_a_plugin(tmp_path):
    with pytest.raises(NotAPluginError):
        load_plugin(tmp_path)


def test_load_reference_plugin(reference_plugins):
    info = load_plugin(reference_plugins["kplanes-static"])
    assert info.method == "kplanes-static" and info.package == "kplanes_static"
    assert info.config == "kplanes_static.config:kplanes_static_method" and info.plan["base"] == "nerfacto"
    assert "kplanes_static/field.py" in info.python_files and ast_checks(info) == []


def test_syntax_error_names_file_and_line(reference_plugins, tmp_path):
    import shutil

    plugin = shutil.copytree(reference_plugins["nerfacto"], tmp_path / "p")
    (plugin / "nerfacto_ref" / "field.py").write_text("x = 1\ndef broken(:\n")
    found = ast_checks(load_plugin(plugin))
    assert [(d.rule, d.file, d.line) for d in found] == [("syntax", "nerfacto_ref/field.py", 2)]


@pytest.mark.skipif(not isolation_available(), reason="needs root and bwrap or unshare for namespaces")
@pytest.mark.parametrize("mode", [m for m in available_modes() if m != "none"])
def test_sandbox_blocks_network_writes_and_time(tmp_path, mode):
    outside = tmp_path / "outside.txt"
    code = (
        f"import socket\nopen('inside.txt','w').write('ok')\n"
        f"try:\n  open({str(outside)!r},'w').write('x'); print('WROTE')\nexcept OSError as e: print('RO', e.errno)\n"
        "try:\n  socket.create_connection(('1.1.1.1', 80), timeout=3); print('NET')\n"
        "except OSError as e: print('NONET', e.errno)\n"
    )
    r = run_sandboxed([sys.executable, "-c", code], tmp_path / "work", timeout=60, mode=mode)
    log = r.log_path.read_text()
    assert r.returncode == 0 and ("RO 30" in log or "RO 13" in log) and "NONET" in log, log
    assert not outside.exists() and (tmp_path / "work" / "inside.txt").exists()
    assert r.mode == mode and "no-network" in r.isolation and "read-only-fs" in r.isolation
    r = run_sandboxed([sys.executable, "-c", "while True: pass"], tmp_path / "loop", timeout=3, mode=mode)
    assert r.timed_out and r.returncode == -9 and r.seconds < 30


def test_sandbox_memory_limit(tmp_path):
    """3 GiB under a 1 GiB limit: killed by the tree's cgroup, or a MemoryError under the per-process rlimit."""
    r = run_sandboxed([sys.executable, "-c", "x = bytearray(3 << 30)"], tmp_path, timeout=60, memory=1 << 30)
    assert r.returncode != 0
    assert r.usage.get("oom_kills") or "MemoryError" in r.log_path.read_text()


def _param_groups(plugin, missing, extra) -> Diagnosis:
    """The static rung's diagnosis for a config whose optimiser keys differ from the parameter groups."""
    config = next(plugin.glob("*/config.py"))
    line = next(i for i, t in enumerate(config.read_text().splitlines(), 1) if "optimizers=" in t)
    return Diagnosis("static", "param-groups", f"model parameter groups != optimizer keys (missing optimizers: "
                     f"{missing}; optimizers without a group: {extra})", str(config.relative_to(plugin)), line,
                     data={"missing": missing, "extra": extra})


def test_optimizer_group_fixer_renames_a_misspelled_key_keeping_its_settings(reference_plugins, tmp_path):
    import shutil

    plugin = shutil.copytree(reference_plugins["kplanes-static"], tmp_path / "p")
    config = plugin / "kplanes_static" / "config.py"
    text = config.read_text()
    start = text.index('"proposal_networks": {')
    lr = text.index("lr=", start)
    text = text[:start] + '"proposal_network": {' + text[start + len('"proposal_networks": {'):lr] + "lr=0.0123," \
        + text[text.index(",", lr) + 1:]
    config.write_text(text)
    d = _param_groups(plugin, ["proposal_networks"], ["proposal_network"])
    (patch,) = OptimizerGroupFixer().propose(load_plugin(plugin), [d])
    assert '"proposal_networks": {' in patch.after and '"proposal_network": {' not in patch.after
    assert "lr=0.0123," in patch.after  # the author's settings stay with the renamed key
    changed = [line for line in patch.diff().splitlines() if line[:1] in "+-" and line[:3] not in ("+++", "---")]
    assert changed == ['-            "proposal_network": {', '+            "proposal_networks": {'], changed
    assert patch.diff().startswith("--- a/kplanes_static/config.py")
    assert [(e.op, e.path, e.value) for e in patch.plan_edits] == [
        ("rename", "optimizers.proposal_network", "optimizers.proposal_networks")]
    compile(patch.after, "config.py", "exec")


def test_optimizer_group_fixer_adds_and_removes_when_nothing_is_close(reference_plugins, tmp_path):
    import shutil

    plugin = shutil.copytree(reference_plugins["kplanes-static"], tmp_path / "p")
    config = plugin / "kplanes_static" / "config.py"
    config.write_text(config.read_text().replace('"proposal_networks": {', '"camera_opt": {'))
    d = _param_groups(plugin, ["proposal_networks"], ["camera_opt"])
    (patch,) = OptimizerGroupFixer().propose(load_plugin(plugin), [d])
    optimizers = next(n.value for n in ast.walk(ast.parse(patch.after))
                      if isinstance(n, ast.keyword) and n.arg == "optimizers")
    keys = [k.value for k in optimizers.keys]
    assert keys == ["fields", "proposal_networks"] and "\"camera_opt\"" not in patch.after, keys
    fields_src, new_src = (ast.get_source_segment(patch.after, v) for v in optimizers.values)
    assert new_src == fields_src  # a group without a plausible key gets a copy of 'fields'
    assert "added (a copy of 'fields')" in patch.reason and "'camera_opt' removed" in patch.reason


def test_pair_misspelled_is_one_to_one():
    from nerfify_ns.verify.repair import pair_misspelled

    assert pair_misspelled(["proposal_networks", "fields"], ["proposal_network", "field", "camera_opt"]) == {
        "proposal_network": "proposal_networks", "field": "fields"}
    assert pair_misspelled(["fields"], ["camera_opt"]) == {}


def test_exp_guard_fixer(reference_plugins, tmp_path):
    import shutil

    plugin = shutil.copytree(reference_plugins["kplanes-static"], tmp_path / "p")
    field = plugin / "kplanes_static" / "field.py"
    guarded = "trunc_exp((density_raw.to(hidden)).clamp(max=20.0))"
    assert guarded in field.read_text()  # the template guards it; unguard it to exercise the fixer
    field.write_text(field.read_text().replace(guarded, "trunc_exp(density_raw.to(hidden))"))
    d = Diagnosis(
        "stability", "stiff-case", "assembled model, case density_raw_1e8: ...", case="density_raw_1e8"
    )
    patches = {p.file: p for p in ExpGuardFixer().propose(load_plugin(plugin), [d])}
    assert "trunc_exp((density_raw.to(hidden)).clamp(max=20.0))" in patches["kplanes_static/field.py"].after
    assert "kplanes_static/components/kplanes.py" not in patches  # already guarded


def test_report_round_trip():
    r = RungResult("static")
    r.fail(Diagnosis("static", "import", "boom", "p/field.py", 3))
    report = LadderReport("x", rungs=[r, RungResult("contract", "skip")])
    data = json.loads(json.dumps(report.to_dict()))
    assert (
        data["ok"] is False
        and data["failures"][0]["line"] == 3
        and str(report.failures[0]).startswith("[static/import]")
    )


def test_static_rung_parses_in_the_sandbox(reference_plugins, tmp_path):
    """A 300,000-deep expression exhausts the parser in a sandboxed subprocess: the rung fails naming the file."""
    import shutil

    from nerfify_ns.verify.rungs import static_ast

    plugin = shutil.copytree(reference_plugins["nerfacto"], tmp_path / "p")
    (plugin / "nerfacto_ref" / "deep.py").write_text("x = " + "-" * 300000 + "1\n")
    (plugin / "nerfacto_ref" / "calls.py").write_text("x = f" + "()" * 300000 + "\n")
    r = static_ast(load_plugin(plugin), tmp_path / "static")
    found = {d.file: d for d in r.failures}
    assert set(found) == {"nerfacto_ref/deep.py", "nerfacto_ref/calls.py"}, [str(d) for d in r.failures]
    assert all(d.rule == "syntax" and "too deeply nested" in d.message for d in found.values())
    assert r.details["sandbox"]["mode"] in available_modes()


def _tree_cgroup() -> bool:
    from nerfify_ns.runtime.sandbox import Limits, TreeCgroup

    group = TreeCgroup.create(Limits())
    if group is not None:
        group.remove()
    return group is not None and "memory" in group.dirs


@pytest.mark.skipif(not _tree_cgroup(), reason="needs a writable memory cgroup (root): the per-process rlimit "
                                                "would stop the interpreter from starting at this limit")
def test_static_rung_parser_crash_is_named(reference_plugins, tmp_path):
    """The parser killed at its memory limit: the rung names the file it was parsing and how it ended."""
    import shutil

    from nerfify_ns.runtime.sandbox import Limits
    from nerfify_ns.verify.rungs import static_ast

    plugin = shutil.copytree(reference_plugins["nerfacto"], tmp_path / "p")
    (plugin / "nerfacto_ref" / "big.py").write_text("x = [" + "(1, 2.5, 'abc'), " * 200000 + "]\n")
    r = static_ast(load_plugin(plugin), tmp_path / "static", limits=Limits(memory=48 << 20, pids=16))
    assert not r.ok
    d = next(d for d in r.failures if d.rule == "syntax")
    assert d.file == "nerfacto_ref/big.py", [str(d) for d in r.failures]
    assert "crashed the parser" in d.message or "too deeply nested or too complex" in d.message


def test_repairs_touch_only_files_inside_the_plugin(reference_plugins, tmp_path):
    """A diagnosis names its file as the sandboxed probe (running plugin code) reported it: a path leading out
    of the plugin, or a link out of it, is neither read nor written by the repairs."""
    import shutil

    from nerfify_ns.verify.errors import VerifyError
    from nerfify_ns.verify.plugin import plugin_file
    from nerfify_ns.verify.repair import CodePatch

    plugin = shutil.copytree(reference_plugins["nerfacto"], tmp_path / "p")
    outside = tmp_path / "outside.txt"
    outside.write_text("secret\n")
    (plugin / "nerfacto_ref" / "link.py").symlink_to(outside)
    assert plugin_file(plugin, "nerfacto_ref/config.py") == "nerfacto_ref/config.py"
    for rel in ("../outside.txt", str(outside), "nerfacto_ref/link.py", "nerfacto_ref", "", None, "x\0y"):
        assert plugin_file(plugin, rel) is None, rel
    d = Diagnosis("static", "param-groups", "forged", "../outside.txt", 1, data={"missing": ["a"], "extra": ["b"]})
    with pytest.raises(VerifyError):  # the fixer would read the file: refused
        OptimizerGroupFixer().propose(load_plugin(plugin), [d])
    with pytest.raises(VerifyError):
        CodePatch("../outside.txt", "secret\n", "overwritten\n", "param-groups", "forged").apply(plugin)
    assert outside.read_text() == "secret\n"
    r = static_ast(load_plugin(plugin), tmp_path / "static")
    assert any(d.file == "nerfacto_ref/link.py" and "not a regular file" in d.message for d in r.failures)


def test_plugin_metadata_read_safely(tmp_path):
    """pyproject.toml, nerfify.json and plan.yaml are read in our own process: deep nesting, huge files and
    alias bombs are refused, not crashes."""
    deep = tmp_path / "deep"
    deep.mkdir()
    (deep / "pyproject.toml").write_text("a = " + "[" * 100000 + "]" * 100000 + "\n")
    (deep / "nerfify.json").write_text("[" * 100000 + "]" * 100000)
    with pytest.raises(NotAPluginError, match=r'\[project.entry-points."nerfstudio.method_configs"\]'):
        load_plugin(deep)
    bomb = tmp_path / "bomb"
    bomb.mkdir()
    (bomb / "pyproject.toml").write_text('[project.entry-points."nerfstudio.method_configs"]\nm = "m.config:spec"\n')
    lines = ['a: &a ["x", "x", "x", "x", "x", "x", "x", "x", "x"]']
    lines += [f"{chr(98 + i)}: &{chr(98 + i)} [" + ", ".join([f"*{chr(97 + i)}"] * 9) + "]" for i in range(20)]
    lines += ["tail: [" + ", ".join(["*u"] * 1000) + "]"]
    (bomb / "plan.yaml").write_text("\n".join(lines) + "\n")
    info = load_plugin(bomb)
    assert info.method == "m" and info.plan is None


def test_verify_cli_shows_the_section_name(tmp_path):
    """A pyproject.toml without the entry point: one error line naming the bracketed section, exit 2."""
    import subprocess
    from pathlib import Path

    (tmp_path / "pyproject.toml").write_text('[project]\nname = "x"\n')
    cli = Path(sys.executable).with_name("ns-nerfify")
    r = subprocess.run([str(cli), "verify", str(tmp_path)], capture_output=True, text=True, timeout=300,
                       env={"COLUMNS": "300", "PATH": "/usr/bin:/bin", "HOME": str(Path.home())})
    assert r.returncode == 2, r.stdout + r.stderr
    assert '[project.entry-points."nerfstudio.method_configs"] in pyproject.toml' in r.stdout + r.stderr


def test_verify_console_shows_plugin_text_escaped():
    """Diagnoses, file names, a fixer's reason and the repair diff carry the plugin's text: the console shows
    its markup literally and its control characters as escapes, never raw."""
    import io

    from rich.console import Console

    from nerfify_ns.verify.command import print_report

    report = LadderReport(plugin="/plugins/x\x1b[2J", repair="apply")
    rung = RungResult("static")
    rung.fail(Diagnosis("static", "import", "boom \x1b]0;pwned\x07 [bold green]verified[/]" + "A" * 5000,
                        "config\x1b.py", traceback="\x1b[2J" * 3000))
    report.rungs = [rung]
    report.diff = "--- a/f.py\n+++ b/f.py\n-x = '\x1b[2J'\n+x = 1\n"
    report.patches = [{"file": "f\x1b.py", "fixer": "fix", "reason": "key '\x1b[31m' renamed", "diff": "d.diff"}]
    out = io.StringIO()
    print_report(report, Console(file=out, force_terminal=True, color_system=None, width=250))
    shown = out.getvalue()
    assert "\x1b" not in shown and "\\x1b" in shown and "[bold green]verified[/]" in shown
    assert len(rung.failures[0].message) < 2100 and len(rung.failures[0].traceback) < 4100


def test_weaker_isolation_is_noted():
    """A rung that ran under the unshare fallback (or none) gets a note in the report and on the console."""
    import io

    from rich.console import Console

    from nerfify_ns.verify.command import print_report
    from nerfify_ns.verify.ladder import _sandbox_notes

    full, weak = RungResult("static"), RungResult("contract")
    full.details["sandbox"], weak.details["sandbox"] = {"mode": "bwrap"}, {"mode": "unshare"}
    assert _sandbox_notes([full]) == []
    (note,) = _sandbox_notes([full, weak])
    assert "unshare" in note and "weaker than bubblewrap" in note
    report = LadderReport(plugin="/p", rungs=[full, weak], notes=[note])
    out = io.StringIO()
    print_report(report, Console(file=out, width=300))
    assert "weaker than bubblewrap" in out.getvalue()
