"""Learned components: the networks and the checkpoint format only. ``cvae`` (the CVAE network and its loss),
``vqvae`` and ``pixelcnn`` (P2's VQ-VAE and its conditional PixelCNN prior over the codes), ``filter`` (P2's learned
safety filter network), ``checkpoint`` (atomic, checksummed files). The loops that train them through the planner and
the simulator are in :mod:`driveopt.training`; the priors that use them for planning in :mod:`driveopt.priors`, the
safety filter's pytree in :mod:`driveopt.safety`."""
