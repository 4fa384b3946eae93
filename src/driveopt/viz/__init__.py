"""Pictures: ``plan_plot`` (one planning call, P1 Fig. 2/6 style), ``prior_plot`` (samples and set-point
densities of several priors for one observation, P2 Fig. 1; ``kde``: the densities), ``curves`` (training
curves of the RL baselines) and ``video`` (MP4 of the closed loop with the plans drawn over it)."""
