"""Ground-truth auditor: judges what really happened to the robot and the people (safety-math.md §9)."""
