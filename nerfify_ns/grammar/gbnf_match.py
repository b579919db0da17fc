"""A recogniser for GBNF grammars: does a string belong to the language?

Used to check a decoded plan against the exported grammar before ``validate`` and, in tests,
that the GBNF export accepts exactly the plans ``validate`` accepts. It parses the GBNF subset
llama.cpp documents (literals, character classes, rule references, groups, ``| ? * + {m,n}``)
and recognises by memoised sets of end positions, which is exact for any grammar without left
recursion (GBNF grammars have none).
"""

from __future__ import annotations

import re
import sys
from dataclasses import dataclass

from nerfify_ns.errors import NerfifyError


class GbnfSyntaxError(NerfifyError):
    """The GBNF text does not parse."""


@dataclass(frozen=True)
class _Node:
    kind: str  # lit | cls | ref | seq | alt | rep
    value: object = None
    items: tuple[_Node, ...] = ()
    lo: int = 0
    hi: int | None = None


_ESCAPES = {"n": "\n", "t": "\t", "r": "\r", "\\": "\\", '"': '"', "]": "]", "[": "[", "-": "-", "/": "/"}


class _Parser:
    def __init__(self, text: str) -> None:
        self.text, self.pos = text, 0

    def error(self, what: str) -> GbnfSyntaxError:
        return GbnfSyntaxError(f"GBNF syntax error at offset {self.pos}: {what}")

    def ws(self) -> None:
        while self.pos < len(self.text) and self.text[self.pos] in " \t\n\r":
            self.pos += 1

    def char(self) -> str:
        c = self.text[self.pos]
        self.pos += 1
        if c != "\\":
            return c
        e = self.text[self.pos]
        self.pos += 1
        if e == "u" or e == "x":
            n = 4 if e == "u" else 2
            code = int(self.text[self.pos:self.pos + n], 16)
            self.pos += n
            return chr(code)
        return _ESCAPES.get(e, e)

    def alternation(self) -> _Node:
        options = [self.sequence()]
        while self.pos < len(self.text) and self.text[self.pos] == "|":
            self.pos += 1
            options.append(self.sequence())
        return options[0] if len(options) == 1 else _Node("alt", items=tuple(options))

    def sequence(self) -> _Node:
        items: list[_Node] = []
        while True:
            self.ws()
            if self.pos >= len(self.text) or self.text[self.pos] in "|)":
                break
            items.append(self.postfix(self.atom()))
        return items[0] if len(items) == 1 else _Node("seq", items=tuple(items))

    def atom(self) -> _Node:
        c = self.text[self.pos]
        if c == '"':
            self.pos += 1
            out = []
            while self.text[self.pos] != '"':
                out.append(self.char())
            self.pos += 1
            return _Node("lit", "".join(out))
        if c == "[":
            self.pos += 1
            negated = self.text[self.pos] == "^"
            self.pos += negated
            ranges = []
            while self.text[self.pos] != "]":
                a = self.char()
                b = a
                if self.text[self.pos] == "-" and self.text[self.pos + 1] != "]":
                    self.pos += 1
                    b = self.char()
                ranges.append((a, b))
            self.pos += 1
            return _Node("cls", (negated, tuple(ranges)))
        if c == "(":
            self.pos += 1
            inner = self.alternation()
            if self.pos >= len(self.text) or self.text[self.pos] != ")":
                raise self.error("missing ')'")
            self.pos += 1
            return inner
        m = re.compile(r"[a-zA-Z0-9-]+").match(self.text, self.pos)
        if not m:
            raise self.error(f"unexpected {c!r}")
        self.pos = m.end()
        return _Node("ref", m.group())

    def postfix(self, node: _Node) -> _Node:
        while self.pos < len(self.text):
            c = self.text[self.pos]
            if c in "?*+":
                self.pos += 1
                node = _Node("rep", items=(node,), lo=int(c == "+"), hi=1 if c == "?" else None)
            elif c == "{":
                m = re.compile(r"\{(\d+)(,(\d*))?\}").match(self.text, self.pos)
                if not m:
                    raise self.error("bad repetition")
                self.pos = m.end()
                lo = int(m.group(1))
                hi = lo if m.group(2) is None else (int(m.group(3)) if m.group(3) else None)
                node = _Node("rep", items=(node,), lo=lo, hi=hi)
            else:
                break
        return node


def _rules(text: str) -> dict[str, _Node]:
    rules: dict[str, _Node] = {}
    chunks = re.split(r"(?m)^([a-zA-Z0-9-]+)\s*::=", "\n".join(
        line for line in text.splitlines() if not line.lstrip().startswith("#")))
    for name, body in zip(chunks[1::2], chunks[2::2], strict=False):
        parser = _Parser(body.strip())
        node = parser.alternation()
        if parser.pos != len(parser.text):
            raise parser.error(f"trailing text in rule {name}")
        rules[name] = node
    return rules


class GbnfGrammar:
    """A parsed GBNF grammar; ``accepts(text)`` tells whether ``root`` derives ``text``."""

    def __init__(self, text: str, root: str = "root") -> None:
        self.rules = _rules(text)
        self.root = root
        missing = {n.value for n in self._refs()} - set(self.rules)
        if missing:
            raise GbnfSyntaxError(f"GBNF grammar refers to undefined rules: {sorted(missing)}")

    def _refs(self):
        stack = list(self.rules.values())
        while stack:
            node = stack.pop()
            if node.kind == "ref":
                yield node
            stack.extend(node.items)

    def accepts(self, text: str) -> bool:
        memo: dict[tuple[str, int], frozenset[int]] = {}
        limit = sys.getrecursionlimit()
        sys.setrecursionlimit(max(limit, 20000))
        try:
            return len(text) in self._ends(self.rules[self.root], 0, text, memo)
        finally:
            sys.setrecursionlimit(limit)

    def _ends(self, node: _Node, pos: int, text: str, memo) -> frozenset[int]:
        kind = node.kind
        if kind == "lit":
            return frozenset([pos + len(node.value)]) if text.startswith(node.value, pos) else frozenset()
        if kind == "cls":
            if pos >= len(text):
                return frozenset()
            negated, ranges = node.value
            inside = any(a <= text[pos] <= b for a, b in ranges)
            return frozenset([pos + 1]) if inside != negated else frozenset()
        if kind == "ref":
            key = (node.value, pos)
            if key not in memo:
                memo[key] = frozenset()  # guards against (absent) left recursion
                memo[key] = self._ends(self.rules[node.value], pos, text, memo)
            return memo[key]
        if kind == "alt":
            return frozenset().union(*(self._ends(o, pos, text, memo) for o in node.items))
        if kind == "seq":
            current = frozenset([pos])
            for item in node.items:
                current = frozenset().union(*(self._ends(item, p, text, memo) for p in current))
                if not current:
                    break
            return current
        inner, reached, frontier, count = node.items[0], set(), {pos}, 0
        if node.lo == 0:
            reached.add(pos)
        seen = set(frontier)
        while frontier and (node.hi is None or count < node.hi):
            frontier = set().union(*(self._ends(inner, p, text, memo) for p in frontier))
            count += 1
            if count >= node.lo:
                reached |= frontier
            frontier -= seen if node.hi is None else set()
            seen |= frontier
        return frozenset(reached)
