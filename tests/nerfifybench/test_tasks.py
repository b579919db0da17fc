"""A failed reference's row says what the command said: ``error_excerpt`` over real shapes of ns-train's output."""

from __future__ import annotations

from nerfify_ns.nerfifybench.tasks import error_excerpt

WARNINGS = ("/x/torch/jit/_script.py:1491: FutureWarning: `torch.jit.script` is deprecated.\n  warnings.warn(\n")


def tyro_box(help_lines: int) -> str:
    """The shape of tyro's answer to an option a method does not take: the error at the top of a long box."""
    suggestions = "".join(f"│         in /venv/bin/ns-train method-{k} --help                   │\n"
                          for k in range(help_lines))
    return (WARNINGS + "╭─ Unrecognized options ─────────────────────────────╮\n"
            "│ Unrecognized or misplaced options:                 │\n"
            "│   --data (applied to /venv/bin/ns-train nerfplayer-nerfacto) │\n"
            "│                                                    │\n"
            "│ Perhaps you meant:                                 │\n" + suggestions +
            "│ For full helptext, run /venv/bin/ns-train --help   │\n"
            "╰────────────────────────────────────────────────────╯\n")


def test_the_error_at_the_top_of_a_long_box_is_the_reason():
    said = error_excerpt(tyro_box(help_lines=400))
    assert said.startswith("Unrecognized options | Unrecognized or misplaced options: | --data (applied to")
    assert "nerfplayer-nerfacto" in said and "method-3" not in said and "│" not in said


def test_a_traceback_gives_its_exception_line():
    log = WARNINGS + ("Traceback (most recent call last):\n  File \"/x/errors_of_mine.py\", line 3, in <module>\n"
                      "    import kplanes\n  File \"/x/kplanes/kplanes.py\", line 9, in <module>\n"
                      "ImportError: cannot import name 'shift_directions_for_tcnn' from 'nerfstudio'\n")
    assert error_excerpt(log) == "ImportError: cannot import name 'shift_directions_for_tcnn' from 'nerfstudio'"


def test_without_an_error_line_the_last_lines_and_a_bounded_length():
    log = "\n".join(f"step {k}" for k in range(100))
    assert error_excerpt(log) == " | ".join(f"step {k}" for k in range(94, 100))
    assert len(error_excerpt("error " + "x" * 5000)) == 400
