"""Ground-truth auditor: judges what really happened to the robot and the people (safety-math.md §9).

Independent of the gateway it audits: its kinematics (:mod:`audit.kinematics`, Pinocchio) and distances
(:mod:`audit.distance`, coal) are its own; no module of ``audit`` imports ``gateway``.
"""

from audit.checks import (
    MOVING_EPS_MPS,
    AuditAccumulator,
    AuditSummary,
    CycleAudit,
    audit_cycle,
    audit_links,
    merge_summaries,
)
from audit.kinematics import LinkMotion, link_motion

__all__ = [
    "MOVING_EPS_MPS",
    "AuditAccumulator",
    "AuditSummary",
    "CycleAudit",
    "LinkMotion",
    "audit_cycle",
    "audit_links",
    "link_motion",
    "merge_summaries",
]
