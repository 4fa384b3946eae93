"""Learned components: networks, training loops and the checkpoint format only. ``cvae`` (the CVAE
network and its loss), ``train_cvae`` (``driveopt train cvae``), ``vqvae`` and ``pixelcnn`` (P2's
VQ-VAE and its conditional PixelCNN prior over the codes), ``train_vqvae`` (``driveopt train vqvae``
and ``driveopt train pixelcnn``), ``filter`` and ``train_filter`` (P2's learned safety filter and
``driveopt train filter``), ``checkpoint`` (atomic, checksummed files). The priors that use them for
planning live in :mod:`driveopt.priors`, the safety filter's pytree in :mod:`driveopt.safety`."""
