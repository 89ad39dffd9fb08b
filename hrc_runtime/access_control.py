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

The gateway's ROS 2 session (``[ros2]``, rmw_zenoh keys; :class:`Ros2Policy`) runs the same kind of access control
with its own keys: members read the ROS domain; the face (CN :data:`ROS2_FACE`) may put only the topics it publishes
and declare only its nodes' and endpoints' tokens; a ROS 2 tracker's certificate (``tracker-<name>``, as in the cell)
only its own topic and its tokens; the tracker emulator every ROS 2 tracker's. Nobody forwards there.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

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
ROS2_FACE = "ros2"
"""The CN of the gateway's ROS 2 session (its face and its ROS 2 trackers' subscriptions)."""


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


def refuse_reserved_tracker_names(trackers: tuple[str, ...]) -> None:
    """Refuse the tracker name whose CN would be the tracker emulator's.

    Raises:
        ConfigError: a tracker named ``emu``.
    """
    reserved = TRACKER_EMULATOR.removeprefix("tracker-")
    if reserved in trackers:
        raise ConfigError(
            f"tracker name {reserved!r} is reserved: its certificate CN would be {TRACKER_EMULATOR!r}, the "
            "tracker emulator's; allowed: any other [a-z0-9_-] name"
        )


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
        refuse_reserved_tracker_names(self.trackers)

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
        (
            *(keys.robot_override(cell, r) for r in policy.robots),
            *(keys.robot_joint_command(cell, r) for r in policy.robots),
            keys.gateway_status(cell),
        ),
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


# ------------------------------------------------------------------------------------------- the ROS 2 session


class Ros2Rights(NamedTuple):
    """Key expressions of one grant on the ROS 2 session (rmw_zenoh's forms).

    Attributes:
        puts: data keys, ``<domain>/<topic>/<type>/<hash>``.
        tokens: liveliness keys, ``@ros2_lv/<domain>/…``.
    """

    puts: tuple[str, ...]
    tokens: tuple[str, ...]


@dataclass(frozen=True)
class Ros2Policy:
    """What the access control of a cell's ROS 2 session is built from. The keys come from the caller, who knows
    rmw_zenoh's key forms and the face's topics (:func:`gateway.ros2_face.ros2_policy`); this module says who.

    Attributes:
        read: what any member may subscribe to, query liveliness on, and is sent (the domain's data and tokens).
        face: what the gateway's face (CN :data:`ROS2_FACE`) may put and declare: its publishers' data keys, its
            nodes' tokens, its publishers' and its tracker subscriptions' tokens.
        trackers: per ROS 2 tracker of the cell, what its certificate may put and declare: its own topic (any
            type and hash: another type or distro is then seen and counted by the gateway, not silently missing)
            and its node's and publisher's tokens.
    """

    read: tuple[str, ...]
    face: Ros2Rights
    trackers: tuple[tuple[str, Ros2Rights], ...]

    def __post_init__(self) -> None:
        refuse_reserved_tracker_names(tuple(name for name, _ in self.trackers))


def ros2_grants(policy: Ros2Policy) -> tuple[Grant, ...]:
    """Every put and liveliness right on the ROS 2 session, by CN: the face, each ROS 2 tracker, the emulator."""
    face = Grant((ROS2_FACE,), policy.face.puts, policy.face.tokens)
    trackers = tuple(Grant((f"tracker-{name}",), rights.puts, rights.tokens) for name, rights in policy.trackers)
    emulator = Grant(
        (TRACKER_EMULATOR,),
        tuple(dict.fromkeys(k for _, rights in policy.trackers for k in rights.puts)),
        tuple(dict.fromkeys(k for _, rights in policy.trackers for k in rights.tokens)),
    )
    return (face, *trackers, emulator) if policy.trackers else (face,)


def _grants_of(policy: CellPolicy | Ros2Policy) -> tuple[Grant, ...]:
    return ros2_grants(policy) if isinstance(policy, Ros2Policy) else grants(policy)


# ------------------------------------------------------------------------------------------ Zenoh's configuration


def may_put(policy: CellPolicy | Ros2Policy, common_name: str, key: str) -> bool:
    """Whether a put on ``key`` from a link whose certificate CN is ``common_name`` passes the policy."""
    return any(
        common_name in g.common_names and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in g.puts)
        for g in _grants_of(policy)
    )


def may_declare_token(policy: CellPolicy | Ros2Policy, common_name: str, key: str) -> bool:
    """Whether a liveliness token on ``key`` from a link whose certificate CN is ``common_name`` passes."""
    return any(
        common_name in g.common_names and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in g.tokens)
        for g in _grants_of(policy)
    )


def zenoh_access_control(policy: CellPolicy | Ros2Policy) -> dict[str, Any]:
    """The ``access_control`` block of a Zenoh configuration enforcing :func:`grants` (the cell's session) or
    :func:`ros2_grants` (the ROS 2 session), default deny."""
    read = list(policy.read) if isinstance(policy, Ros2Policy) else [READ_KEY_EXPR]
    read_messages = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query"]
    rules: list[dict[str, Any]] = [
        _rule("members-read", read_messages, ["ingress", "egress"], read),
        _rule("members-are-sent", ["put", "liveliness_token"], ["egress"], read),
    ]
    # Any link that completed mutual TLS carries a certificate of the cell CA: that is what "member" means.
    subjects: list[dict[str, Any]] = [{"id": "members", "link_protocols": ["tls"]}]
    policies: list[dict[str, Any]] = [
        {"id": "members", "rules": ["members-read", "members-are-sent"], "subjects": ["members"]}
    ]
    for i, grant in enumerate(_grants_of(policy)):
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
