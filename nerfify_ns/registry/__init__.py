"""The terminal registry: every technique of the grammar defined once.

    from nerfify_ns.registry import default_registry
    reg = default_registry()
    reg["hash"].contract          # named tensors with symbolic shapes, checked by the contract rung
    reg["hash"].param_specs       # typed parameters (from the Hash dataclass)
    reg.interfaces["PosEncoding"] # what a `custom` component of a production must implement
    reg.grammar_data()            # what grammar_spec.yaml exports

A terminal's definition (``TerminalDef``) holds its production, typed parameters, card,
implementation, the code it renders into a plugin, its contract as data and how the ladder builds and
runs it at small sizes. The nonterminals are data (``productions.yaml``).
"""

from nerfify_ns.registry.contract import Contract, ContractSpecError, TensorSpec, check_outputs
from nerfify_ns.registry.core import Registry, RegistryError, default_registry
from nerfify_ns.registry.params import ParamSpec, param, param_specs
from nerfify_ns.registry.terminal import Code, Harness, TerminalDef

__all__ = ["Code", "Contract", "ContractSpecError", "Harness", "ParamSpec", "Registry", "RegistryError",
           "TensorSpec", "TerminalDef", "check_outputs", "default_registry", "param", "param_specs"]
