"""A content-addressed response cache (sqlite): a rerun gives the same answers without calls, and a run that
crashed resumes from the answers it had (each is committed as it arrives).

The key is the SHA-256 of the canonical JSON of backend, model, messages, constraint (schema, grammar) and
sampling parameters (``Request.key_data``); the endpoint's address is not part of it (the same model served
elsewhere answers the same), and neither is a key: nothing secret is ever written here.
"""

from __future__ import annotations

import hashlib
import json
import sqlite3
import time
from pathlib import Path

from nerfify_ns.agents.providers import Response

SCHEMA = """CREATE TABLE IF NOT EXISTS responses (
    key TEXT PRIMARY KEY, backend TEXT, model TEXT, created REAL,
    text TEXT, finish TEXT, input_tokens INTEGER, output_tokens INTEGER)"""


def cache_key(data: dict) -> str:
    return hashlib.sha256(json.dumps(data, sort_keys=True, separators=(",", ":"), default=str).encode()).hexdigest()


class ResponseCache:
    """``get(key)`` / ``put(key, response)`` over one sqlite file (``None`` path: a cache that keeps nothing)."""

    def __init__(self, path: Path | None) -> None:
        self.path = Path(path) if path is not None else None
        self._db: sqlite3.Connection | None = None
        if self.path is not None:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._db = sqlite3.connect(str(self.path), timeout=30)
            self._db.execute(SCHEMA)
            self._db.commit()

    def get(self, key: str) -> Response | None:
        if self._db is None:
            return None
        row = self._db.execute("SELECT text, finish, input_tokens, output_tokens, model FROM responses "
                               "WHERE key = ?", (key,)).fetchone()
        if row is None:
            return None
        return Response(text=row[0], finish=row[1], input_tokens=row[2], output_tokens=row[3], model=row[4],
                        cached=True)

    def put(self, key: str, response: Response, backend: str) -> None:
        if self._db is None:
            return
        self._db.execute("INSERT OR REPLACE INTO responses VALUES (?, ?, ?, ?, ?, ?, ?, ?)",
                         (key, backend, response.model, time.time(), response.text, response.finish,
                          response.input_tokens, response.output_tokens))
        self._db.commit()

    def __bool__(self) -> bool:
        """Always true: an empty cache is still the cache to use (``cache or default`` must not drop it)."""
        return True

    def __len__(self) -> int:
        return 0 if self._db is None else self._db.execute("SELECT COUNT(*) FROM responses").fetchone()[0]

    def close(self) -> None:
        if self._db is not None:
            self._db.close()
            self._db = None
