"""Pictures: ``plan_plot`` (one planning call, P1 Fig. 2/6 style), ``prior_plot`` (samples of several
priors for one observation) and ``video`` (MP4 of the closed loop with the plans drawn over it)."""
