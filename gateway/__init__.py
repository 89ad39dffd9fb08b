"""The safety gateway: delay-aware speed override for a closed robot controller."""
