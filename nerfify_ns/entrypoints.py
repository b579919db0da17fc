"""Nerfstudio entry points of nerfify-ns (group ``nerfstudio.method_configs``).

Loading this module is how a plain ``ns-train`` picks up our CPU/offline runtime: Nerfstudio
imports every entry point while discovering methods, before it builds any model.
"""

from __future__ import annotations

from nerfify_ns.runtime import activate

activate()

from nerfify_ns.synthesis.generated import generated_method  # noqa: E402  (after the runtime is active)

nerfify_generated = generated_method()
