"""The project's exception tree: one root, :class:`HrcError`, for every error the project raises on purpose.

A leaf module (it imports nothing of the project), so that the wire messages can use it and stay a leaf.

    HrcError
    ├── ConfigError      (hrc_common.config)      a configuration that cannot load or is unsafe: refuse to start
    ├── MessageError     (hrc_common.messages)    a payload that is not a valid message: count it, fail closed
    ├── RuleError        (faultinject.rules)      a fault-injection rule that does not parse
    ├── RelayError       (faultinject.relay)      the fault relay cannot run
    └── BenchError       (bench.procs)            a benchmark could not run

Every message says what was given and what is allowed.
"""

from __future__ import annotations


class HrcError(Exception):
    """Root of the errors raised by hrc-gateway's programs and libraries."""
