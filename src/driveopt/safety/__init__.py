"""Safety filters that plug into the planner's batch projection: ``learned`` (P2's learned filter as a pytree, its
weights and their loading; the network itself is :mod:`driveopt.learned.filter`). The contract every filter meets
(``SafetyFilter``, ``FilterInit``, ``check_filter_init``) is :mod:`driveopt.filtering`, re-exported here."""

from driveopt.filtering import FilterError, FilterInit, SafetyFilter, check_filter_init
from driveopt.safety.learned import LearnedFilter, filter_for, load_filter

__all__ = ["FilterError", "FilterInit", "LearnedFilter", "SafetyFilter", "check_filter_init", "filter_for", "load_filter"]
