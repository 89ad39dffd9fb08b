"""Seeded mutations of valid JSON payloads, to hold a fast parser to its reference (tests/hrc_contract)."""

from __future__ import annotations

import json

import numpy as np


def mutate_payload(rng: np.random.Generator, payload: bytes) -> bytes:
    """One random mutation of a valid payload: a value swapped, a key dropped or added, a byte changed or
    inserted, a number token replaced."""
    try:
        raw = json.loads(payload)
    except ValueError:  # already mutated beyond JSON: bytes only
        raw = None
    kind = int(rng.integers(6)) if isinstance(raw, dict) and raw else int(rng.integers(3, 6))
    values = [None, True, 0, -1, 0.5, -0.0, 1e308, 2**70, "1", "0.5", "1e400", "NaN", "", [], {}, [0.1] * 6]
    if kind == 0:
        raw[str(rng.choice(sorted(raw)))] = values[int(rng.integers(len(values)))]
        return json.dumps(raw).encode()
    if kind == 1:
        del raw[str(rng.choice(sorted(raw)))]
        return json.dumps(raw).encode()
    if kind == 2:
        raw[str(rng.choice(["extra", "schema_", "seq"]))] = values[int(rng.integers(len(values)))]
        return json.dumps(raw).encode()
    data = bytearray(payload)
    i = int(rng.integers(len(data)))
    if kind == 3:
        data[i] = int(rng.integers(256))
    elif kind == 4:
        data[i:i] = bytes([int(rng.choice([0, 9, 10, 0x1F, 0x7F, 0xFF, 0xC3, ord('"'), ord("\\"), ord("]")]))])
    else:
        token = str(rng.choice(["NaN", "Infinity", "-Infinity", "1e400", "-1e400", "1e-400", "1E2", "-0", "9" * 30]))
        return payload.replace(b"0.", token.encode() + b"+0.", 1).replace(b"+0.", b"", 1)
    return bytes(data)


def random_float_token(rng: np.random.Generator) -> str:
    digits = "".join(str(d) for d in rng.integers(0, 10, int(rng.integers(1, 25))))
    token = digits[0] + ("." + digits[1:] if len(digits) > 1 else "")
    if rng.random() < 0.7:
        token += f"e{int(rng.integers(-330, 310))}"
    return ("-" if rng.random() < 0.3 else "") + token
