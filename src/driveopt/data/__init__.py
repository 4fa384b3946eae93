"""Expert demonstrations: ``demonstrations`` (the HDF5 format: schema, append, load, fingerprint),
``modes`` (the distinct feasible plans of the expert's first and final batches stored with every step),
``collect`` (``driveopt collect``: the expert in closed loop, resumable) and ``replay`` (the planning
problem of a stored row, for offline evaluation)."""
