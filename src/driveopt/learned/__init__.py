"""Learned components: networks, training loops and the checkpoint format only. ``cvae`` (the CVAE
network and its loss), ``train_cvae`` (``driveopt train cvae``), ``checkpoint`` (atomic, checksummed
files). The priors that use them for planning live in :mod:`driveopt.priors`."""
