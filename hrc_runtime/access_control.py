"""Who may put what on a cell's Zenoh keys: the policy every program enforces on what it receives.

Every program, router and relay of a cell runs the same Zenoh access control (default deny), built here from
the cell's name, robots and trackers. A link is identified by the common name (CN) of the certificate its
other end presented in mutual TLS (roles and CNs: :mod:`hrc_runtime.pki`):

- Any member of the cell (any certificate of the cell CA) may subscribe, declare liveliness subscribers and
  query liveliness on ``hrc/**``, and is sent the puts and liveliness tokens it subscribed to: reading is
  open inside the cell, an observer is a member with no put right.
- Puts and liveliness tokens are accepted only from the CNs that :func:`grants` lists for the key. A message
  that is not allowed is dropped by the receiving session before any subscriber or route sees it.
- A session that routes for others sends their messages on its own link, under its own CN: the router and
  the relay, and the gateway (a Zenoh peer routes for the clients connected to it, e.g. an auditor or an
  observer). Each is granted every put of the cell, and filters with this same policy what it lets in: a
  forwarded message was checked at the first hop. (The gateway commands the robot anyway.)

Not covered: deletes, queries and queryables (none in the contract) are denied to everyone.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import zenoh

from hrc_contract import keys
from hrc_contract.config import CellConfig, ConfigError

READ_KEY_EXPR = "hrc/**"
"""What any member of the cell may subscribe to, and is sent."""
FORWARDERS = ("gateway", "router", "relay")
"""CNs that forward other programs' messages: the gateway (to its Zenoh clients), :mod:`hrc_tools.router.main`,
``hrc-fault-relay``."""
TRACKER_EMULATOR = "tracker-emu"
AUDITOR = "observer-audit"
OPERATOR = "operator"
"""The operator station's CN: may put only the reset of a lost person (``hrc.track_reset/1``)."""
RECORDER = "recorder"
"""``hrc-record``'s CN: a member with no grant, so it reads every topic of the cell and may put on none."""


@dataclass(frozen=True)
class Grant:
    """What the holders of some CNs may put and declare as liveliness tokens.

    Attributes:
        common_names: certificate CNs the grant applies to.
        puts: key expressions they may put on.
        tokens: key expressions they may declare liveliness tokens on.
    """

    common_names: tuple[str, ...]
    puts: tuple[str, ...]
    tokens: tuple[str, ...]


@dataclass(frozen=True)
class CellPolicy:
    """The names the access control of a cell is built from.

    Attributes:
        cell: the cell's name (second segment of every key).
        robots: the cell's robots (one controller each).
        trackers: the cell's trackers.
    """

    cell: str
    robots: tuple[str, ...]
    trackers: tuple[str, ...]

    def __post_init__(self) -> None:
        reserved = TRACKER_EMULATOR.removeprefix("tracker-")
        if reserved in self.trackers:
            raise ConfigError(
                f"tracker name {reserved!r} is reserved: its certificate CN would be {TRACKER_EMULATOR!r}, the "
                "tracker emulator's; allowed: any other [a-z0-9_-] name"
            )

    @classmethod
    def from_config(cls, config: CellConfig) -> CellPolicy:
        return cls(config.cell, tuple(sorted(config.robots)), tuple(sorted(config.trackers)))


def program_common_names(policy: CellPolicy) -> tuple[str, ...]:
    """The identities the programs of a cell on one machine use (``hrc-cell``): gateway, one controller emulator
    per robot, the tracker emulator, and the auditor (an observer)."""
    return ("gateway", *(f"controller-{r}" for r in policy.robots), TRACKER_EMULATOR, AUDITOR)


def control_key(cell: str) -> str:
    """The fault relay's run-time control key of this cell (``hrc-fault-relay --control-key``)."""
    return f"hrc/{cell}/faultinject/control"


def grants(policy: CellPolicy) -> tuple[Grant, ...]:
    """Every put and liveliness right of the cell, by CN."""
    cell = policy.cell
    gateway = Grant(
        ("gateway",),
        (*(keys.robot_override(cell, r) for r in policy.robots), keys.gateway_status(cell)),
        (keys.alive(cell, "gateway"),),
    )
    controllers = tuple(
        Grant(
            (f"controller-{r}",),
            (
                keys.robot_state(cell, r),
                keys.truth_robot_state(cell, r),
                keys.robot_emu_stats(cell, r),
                keys.robot_bridge_stats(cell, r),  # the bridge runs with the controller's certificate
            ),
            (keys.alive(cell, f"controller-{r}"),),
        )
        for r in policy.robots
    )
    trackers = tuple(
        Grant((f"tracker-{t}",), (keys.tracker_humans(cell, t),), (keys.alive(cell, f"tracker-{t}"),))
        for t in policy.trackers
    )
    emulator = Grant(
        (TRACKER_EMULATOR,),
        (*(keys.tracker_humans(cell, t) for t in policy.trackers), keys.truth_humans(cell)),
        (keys.alive(cell, TRACKER_EMULATOR),),
    )
    operator = Grant((OPERATOR,), (keys.operator_track_reset(cell),), (keys.alive(cell, OPERATOR),))
    own = (gateway, *controllers, *trackers, emulator, operator)
    every_put = tuple(dict.fromkeys(k for g in own for k in g.puts))
    forwarders = Grant(FORWARDERS, (*every_put, control_key(cell)), (keys.alive(cell, "*"),))
    return (*own, forwarders)


def may_put(policy: CellPolicy, common_name: str, key: str) -> bool:
    """Whether a put on ``key`` from a link whose certificate CN is ``common_name`` passes the policy."""
    return any(
        common_name in g.common_names and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in g.puts)
        for g in grants(policy)
    )


def zenoh_access_control(policy: CellPolicy) -> dict[str, Any]:
    """The ``access_control`` block of a Zenoh configuration enforcing :func:`grants` (default deny)."""
    read_messages = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
    rules: list[dict[str, Any]] = [
        _rule("members-read", read_messages, ["ingress", "egress"], [READ_KEY_EXPR]),
        _rule("members-are-sent", ["put", "liveliness_token"], ["egress"], [READ_KEY_EXPR]),
    ]
    # Any link that completed mutual TLS carries a certificate of the cell CA: that is what "member" means.
    subjects: list[dict[str, Any]] = [{"id": "members", "link_protocols": ["tls"]}]
    policies: list[dict[str, Any]] = [
        {"id": "members", "rules": ["members-read", "members-are-sent"], "subjects": ["members"]}
    ]
    for i, grant in enumerate(grants(policy)):
        rules.append(_rule(f"put-{i}", ["put"], ["ingress"], list(grant.puts)))
        rules.append(_rule(f"token-{i}", ["liveliness_token"], ["ingress"], list(grant.tokens)))
        subjects.append({"id": f"cn-{i}", "cert_common_names": list(grant.common_names)})
        policies.append({"id": f"grant-{i}", "rules": [f"put-{i}", f"token-{i}"], "subjects": [f"cn-{i}"]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": subjects,
        "policies": policies,
    }


def _rule(rule_id: str, messages: list[str], flows: list[str], key_exprs: list[str]) -> dict[str, Any]:
    return {"id": rule_id, "messages": messages, "flows": flows, "permission": "allow", "key_exprs": key_exprs}
