"""driveopt's measurement scripts, by kind: ``perf`` (how fast, and where the time goes), ``studies`` (the runs behind
the results pages, and the campaigns that produce their records), ``tools`` (for developers of driveopt). A package so
that the tests and the scripts import them by name (``from benchmarks.perf import latency``); each script still runs
as a file from the repository root (``python benchmarks/perf/latency.py ...``). Not installed with driveopt."""
