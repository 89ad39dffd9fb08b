"""Ground-truth auditor: judges what really happened to the robot and the people (safety-math.md §9)."""

from audit.checks import (
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
    "audit_cycle",
    "audit_links",
    "merge_summaries",
]
