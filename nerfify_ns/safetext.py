"""Text written by code we do not trust (a plugin's messages, tracebacks and logs), made safe to show: control
characters (terminal escapes, carriage returns, bidirectional overrides) written as escapes, and the length
bounded. Rich markup is escaped where the text is printed (``rich.markup.escape``); JSON escapes by itself."""

from __future__ import annotations

import re

_CONTROL = re.compile("[\x00-\x08\x0b-\x1f\x7f-\x9f\u200b-\u200f\u2028\u2029\u202a-\u202e"
                      "\u2060-\u2064\u2066-\u2069\ufeff]")


def _escape(match: re.Match[str]) -> str:
    ch = match.group()
    code = ord(ch)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}"


def clean(text: object, limit: int = 2000, *, newlines: bool = True, keep: str = "head") -> str:
    """``text`` with control characters escaped (newlines and tabs kept when ``newlines``, else shown as
    spaces) and at most about ``limit`` characters: the start (``keep="head"``) or the end (``"tail"``), saying
    how much was cut."""
    text = str(text)
    dropped = max(0, len(text) - 4 * limit)  # bound the work before escaping
    if dropped:
        text = text[: 4 * limit] if keep == "head" else text[-4 * limit:]
    text = text.replace("\r\n", "\n")
    if not newlines:
        text = text.replace("\n", " ").replace("\t", " ")
    text = _CONTROL.sub(_escape, text)
    if len(text) <= limit:
        return text
    cut = len(text) - limit + dropped
    if keep == "tail":
        return f"[{cut} characters cut] " + text[-limit:]
    return text[:limit] + f" [{cut} characters cut]"
