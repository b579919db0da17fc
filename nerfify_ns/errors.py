"""The root of nerfify-ns' typed exceptions: the CLI turns any of them into a one-line message.

A leaf module (imports nothing), so every package, the leaf ones included, can derive from it.
"""


class NerfifyError(Exception):
    """An error the user can act on; its message says what went wrong and what to do."""
