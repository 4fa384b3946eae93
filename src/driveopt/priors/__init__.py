"""Priors: where the first batch of set-points of a planning call comes from.

The contract (``Prior``, ``Proposal``, ``moments``) and the default, P1's Gaussian with driveopt's coherent
behaviours (``GaussianPrior``), sit with the sampler in :mod:`driveopt.sampler` and are re-exported here. This
package holds the others: :mod:`~driveopt.priors.grids` (the MPC baselines' grids), :mod:`~driveopt.priors.p1_authors`
(P1's planners' proposals as P1's authors' code draws them), :mod:`~driveopt.priors.cvae`
(the learned CVAE) and :mod:`~driveopt.priors.vqvae` (P2's VQ-VAE + PixelCNN); the learned ones are imported on
demand (they need Flax). :mod:`driveopt.experiments.prior_metrics` measures any prior's first batch offline.
"""

from driveopt.priors.grids import GoalGridPrior, GridPrior, VanillaPrior
from driveopt.priors.p1_authors import BatchGoals, FixedGaussian, SpeedOffsetGrid, VanillaGuesses
from driveopt.sampler import GaussianPrior, Prior, Proposal, clip_setpoints, coherent_behaviours, default_mean, moments

__all__ = ["Prior", "Proposal", "clip_setpoints", "default_mean", "moments", "GaussianPrior", "coherent_behaviours",
           "GoalGridPrior", "GridPrior", "VanillaPrior", "FixedGaussian", "SpeedOffsetGrid", "VanillaGuesses",
           "BatchGoals"]
