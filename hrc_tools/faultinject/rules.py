"""Fault rules of the relay: which messages, which direction, and what happens to them. Pure, no I/O.

A rule is written ``KEYEXPR:param=value,...``, for example::

    hrc/*/tracker/**:delay=0.1,jitter=0.02,loss=0.05,dup=0.01
    hrc/*/robot/*/override:delay=0.08,dir=b2a

Parameters (all optional; times in seconds, probabilities in [0, 1]):

- ``delay``: fixed one-way delay added to every message [s];
- ``jitter``: each message's delay is drawn uniformly from ``delay ± jitter`` (never below 0) [s];
- ``loss``: probability that a message is dropped;
- ``dup``: probability that a message is delivered twice (the copy right after the original);
- ``reorder``: probability that a message is held back by a further ``reorder_delay`` and overtaken
  by the messages that follow it;
- ``reorder_delay``: the extra hold of a reordered message [s] (default 0.05);
- ``dir``: ``a2b``, ``b2a`` or ``both`` (default ``both``).

Apart from ``reorder``, a key's messages keep their order in each direction: with jitter, a message is
never delivered before the one of the same key that came in before it (like a TCP link whose latency
varies). The first rule whose key expression includes a message's key decides its fate; a message no
rule matches is forwarded at once.
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from typing import Literal, get_args

import zenoh

from hrc_contract.errors import HrcError

Direction = Literal["a2b", "b2a"]
DIRECTIONS: tuple[Direction, ...] = get_args(Direction)

DEFAULT_REORDER_DELAY_S = 0.05
MAX_DELAY_S = 60.0

_PROBABILITIES = ("loss", "dup", "reorder")
_TIMES = ("delay", "jitter", "reorder_delay")
ALLOWED_PARAMS = (*_TIMES, *_PROBABILITIES, "dir")


class RuleError(HrcError, ValueError):
    """A rule that cannot be parsed; the message is one line and says what is allowed."""


@dataclass(frozen=True)
class FaultRule:
    """What happens to the messages of one key expression in some directions.

    Attributes:
        key_expr: Zenoh key expression of the messages concerned.
        directions: the directions the rule applies to.
        delay_s: fixed one-way delay [s].
        jitter_s: half-width of the uniform spread of the delay [s].
        loss: probability of dropping a message.
        dup: probability of delivering a message twice.
        reorder: probability of holding a message back so that later ones overtake it.
        reorder_delay_s: how long a reordered message is held back beyond its delay [s].
    """

    key_expr: str
    directions: frozenset[Direction] = frozenset(DIRECTIONS)
    delay_s: float = 0.0
    jitter_s: float = 0.0
    loss: float = 0.0
    dup: float = 0.0
    reorder: float = 0.0
    reorder_delay_s: float = DEFAULT_REORDER_DELAY_S

    def __post_init__(self) -> None:
        for name in ("delay_s", "jitter_s", "reorder_delay_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= MAX_DELAY_S):
                raise RuleError(f"rule {self.key_expr!r}: {name} = {value}; allowed: 0 to {MAX_DELAY_S} s")
        for name in _PROBABILITIES:
            value = getattr(self, name)
            if not (math.isfinite(value) and 0.0 <= value <= 1.0):
                raise RuleError(f"rule {self.key_expr!r}: {name} = {value}; allowed: a probability in [0, 1]")
        if not self.directions or not self.directions <= set(DIRECTIONS):
            raise RuleError(f"rule {self.key_expr!r}: directions {sorted(self.directions)}; allowed: a2b, b2a")
        try:
            zenoh.KeyExpr(self.key_expr)
        except (zenoh.ZError, ValueError) as exc:
            reason = str(exc).split(" at /", 1)[0]
            raise RuleError(f"rule {self.key_expr!r}: not a valid key expression: {reason}") from None

    def matches(self, key: str, direction: Direction) -> bool:
        """True if the rule applies to a message on ``key`` going in ``direction``."""
        return direction in self.directions and zenoh.KeyExpr(self.key_expr).includes(key)


def parse_rule(text: str) -> FaultRule:
    """Parse ``KEYEXPR:param=value,...`` (see the module docstring).

    Raises:
        RuleError: no ``:``, an unknown parameter, a value that is not a number, or a value out of range.
    """
    key_expr, sep, params = text.strip().rpartition(":")
    if not sep or not key_expr:
        raise RuleError(f"rule {text!r}: expected KEYEXPR:param=value,...; allowed params: {', '.join(ALLOWED_PARAMS)}")
    values: dict[str, float] = {}
    directions: frozenset[Direction] = frozenset(DIRECTIONS)
    for item in filter(None, (p.strip() for p in params.split(","))):
        name, eq, value = item.partition("=")
        name, value = name.strip(), value.strip()
        if not eq or name not in ALLOWED_PARAMS:
            raise RuleError(f"rule {text!r}: {item!r}; allowed params: {', '.join(ALLOWED_PARAMS)} (as name=value)")
        if name == "dir":
            if value == "both":
                directions = frozenset(DIRECTIONS)
            elif value in DIRECTIONS:
                directions = frozenset({value})
            else:
                raise RuleError(f"rule {text!r}: dir={value}; allowed: a2b, b2a, both")
            continue
        try:
            values[name] = float(value)
        except ValueError:
            raise RuleError(f"rule {text!r}: {name}={value!r} is not a number") from None
    return FaultRule(
        key_expr=key_expr,
        directions=directions,
        delay_s=values.get("delay", 0.0),
        jitter_s=values.get("jitter", 0.0),
        loss=values.get("loss", 0.0),
        dup=values.get("dup", 0.0),
        reorder=values.get("reorder", 0.0),
        reorder_delay_s=values.get("reorder_delay", DEFAULT_REORDER_DELAY_S),
    )


@dataclass(frozen=True)
class Fate:
    """What happens to one message: delivered at these times after reception (none: lost).

    Attributes:
        offsets_s: delivery times after reception, one per copy, in order [s]; empty when lost.
        reordered: the first copy is held back and exempt from the key's order.
    """

    offsets_s: tuple[float, ...]
    reordered: bool = False

    @property
    def lost(self) -> bool:
        return not self.offsets_s


FORWARD_NOW = Fate((0.0,))


def draw_fate(rule: FaultRule | None, rng: random.Random) -> Fate:
    """Draw the fate of one message under ``rule`` (None: forwarded at once).

    Always draws the same number of random numbers per message, so that a seed gives the same fates
    whatever the outcomes.
    """
    if rule is None:
        return FORWARD_NOW
    u_loss, u_jitter, u_dup, u_reorder = rng.random(), rng.random(), rng.random(), rng.random()
    if u_loss < rule.loss:
        return Fate(())
    delay_s = max(0.0, rule.delay_s + (2.0 * u_jitter - 1.0) * rule.jitter_s)
    reordered = u_reorder < rule.reorder
    if reordered:
        delay_s += rule.reorder_delay_s
    copies = 2 if u_dup < rule.dup else 1
    return Fate((delay_s,) * copies, reordered)


def first_match(rules: tuple[FaultRule, ...], key: str, direction: Direction) -> FaultRule | None:
    """The first rule that applies to ``key`` in ``direction``, or None."""
    return next((rule for rule in rules if rule.matches(key, direction)), None)
