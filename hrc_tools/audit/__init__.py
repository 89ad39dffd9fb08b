"""Ground-truth auditor: judges what really happened to the robot and the people (safety-math.md §9).

Independent of the gateway it audits: its kinematics (:mod:`hrc_devices.robots.link_motion`, Pinocchio) and distances
(:mod:`hrc_tools.audit.distance`, coal) are its own; no module of ``audit`` imports ``gateway``.
"""

from hrc_devices.robots.link_motion import LinkMotion, link_motion
from hrc_tools.audit.checks import (
    MOVING_EPS_MPS,
    AuditAccumulator,
    AuditSummary,
    CycleAudit,
    audit_cycle,
    audit_links,
    merge_summaries,
)

__all__ = [
    "MOVING_EPS_MPS",
    "AuditAccumulator",
    "AuditSummary",
    "CycleAudit",
    "LinkMotion",
    "audit_cycle",
    "audit_links",
    "bounded",
    "checks",
    "contact",
    "distance",
    "link_motion",
    "main",
    "merge_summaries",
]
