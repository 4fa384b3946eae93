"""Expert demonstrations: ``demonstrations`` (the HDF5 format: schema, append, load, fingerprint),
``modes`` (the distinct feasible plans of the expert's first and final batches stored with every step) and
``replay`` (the planning problem of a stored row, for offline evaluation). They are written by
:mod:`driveopt.experiments.collect` (``driveopt collect``) and read by :mod:`driveopt.training`."""
