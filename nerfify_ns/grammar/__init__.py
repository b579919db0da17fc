"""Stage 3 (``plan``): Nerfstudio as a grammar (``grammar_spec.yaml``); a plan is a derivation in it.

    from nerfify_ns.grammar import load_grammar, validate, to_json_schema, to_gbnf
"""

from nerfify_ns.grammar.spec import Grammar, GrammarSpecError, Nonterminal, Param, Slot, Terminal, load_grammar
from nerfify_ns.grammar.validate import Derivation, PlanError, Violation, check, derive, validate

__all__ = [
    "Derivation", "Grammar", "GrammarSpecError", "Nonterminal", "Param", "PlanError", "Slot", "Terminal",
    "Violation", "check", "derive", "load_grammar", "validate",
]
