"""Safety filters: what sets up the batch projection of every sampler batch. ``base`` (the ``SafetyFilter``
protocol, ``FilterInit``, ``check_filter_init``) and ``learned`` (P2's learned filter as a pytree, its
weights and their loading; the network itself is :mod:`driveopt.learned.filter`)."""

from driveopt.filtering import FilterError, FilterInit, SafetyFilter, check_filter_init
from driveopt.safety.learned import LearnedFilter, filter_for, load_filter

__all__ = ["FilterError", "FilterInit", "LearnedFilter", "SafetyFilter", "check_filter_init", "filter_for", "load_filter"]
