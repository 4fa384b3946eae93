"""Safety filters: what sets up the batch projection of every sampler batch (P2's learned filter lives here)."""

from driveopt.safety.base import FilterInit, SafetyFilter

__all__ = ["FilterInit", "SafetyFilter"]
