"""What crosses a process boundary or has a schema: messages, keys, status models, the vocabulary (zones, modes, fault
codes), the cell file's models, human capsules and every exception.

The bottom layer: imports only pydantic, numpy and the standard library. ``python -m hrc_contract.contract`` writes
and checks the JSON Schemas in ``docs/schemas``.
"""

__all__ = [
    "config",
    "contract",
    "errors",
    "humans",
    "keys",
    "messages",
    "status_models",
    "vocabulary",
]
