"""``--equations`` reuses a generated component only when its code still matches the digest recorded when it was
generated: a component edited next to equations.yaml (or replaced by a link, or from a file without the digest) is
compiled again from the equations, and the hole's notes say why."""

from __future__ import annotations

import yaml
from novel_papers import GATENERF

from nerfify_ns.paper import ingest
from nerfify_ns.synthesis.novel import IMPLEMENTED, implement_holes
from nerfify_ns.synthesis.novel.records import RECOMPILE_NOTE, read_corrections, source_hash, write_records
from nerfify_ns.synthesis.plan_from_paper import plan_from_paper

PAYLOAD = "\nimport os\nos.system('touch /tmp/owned')  # appended by someone else\n"


def test_a_tampered_component_is_recompiled_and_says_so(tmp_path):
    paper = tmp_path / "gatenerf.md"
    paper.write_text(GATENERF)
    doc = ingest(paper)
    derived = plan_from_paper(doc)
    result = implement_holes(doc, derived.plan)
    (record,) = result.records
    assert record.status == IMPLEMENTED, record.reason
    run = tmp_path / "run"
    run.mkdir()
    write_records(run, result, doc)
    data = yaml.safe_load((run / "equations.yaml").read_text())
    assert data["holes"][0]["source_hash"] == source_hash(record.source)

    corrections, reuse = read_corrections(run / "equations.yaml")  # untouched: reused as before
    assert not corrections["holes"] and list(reuse) == ["backbone"] and reuse["backbone"].source == record.source

    component = run / "equations" / "backbone.py"
    component.write_text(record.source + PAYLOAD)
    corrections, reuse = read_corrections(run / "equations.yaml")
    assert not reuse and [h["id"] for h in corrections["holes"]] == ["backbone"]
    assert "does not match the source_hash" in corrections["holes"][0][RECOMPILE_NOTE]
    again = implement_holes(doc, derived.plan, corrections=corrections, reuse=reuse)
    (redone,) = again.records
    assert redone.status == IMPLEMENTED and "os.system" not in redone.source and redone.source == record.source
    assert any("does not match the source_hash" in n and "compiled again" in n for n in redone.notes)
    assert not any(n.startswith("not recompiled") for n in redone.notes)

    component.unlink()
    outside = tmp_path / "elsewhere.py"
    outside.write_text(record.source)  # the same code, but through a link: not read
    component.symlink_to(outside)
    corrections, reuse = read_corrections(run / "equations.yaml")
    assert not reuse and "is a symbolic link" in corrections["holes"][0][RECOMPILE_NOTE]

    component.unlink()
    component.write_text(record.source)
    del data["holes"][0]["source_hash"]  # a file written before the digest was recorded
    (run / "equations.yaml").write_text(yaml.safe_dump(data, sort_keys=False))
    corrections, reuse = read_corrections(run / "equations.yaml")
    assert not reuse and "no source_hash recorded" in corrections["holes"][0][RECOMPILE_NOTE]
