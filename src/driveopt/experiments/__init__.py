"""Experiments: closed-loop episodes and what is measured over many of them, resumably. ``rollout`` (the episode
loop, given a driver spec), ``store`` (append-only JSONL records and the job key), ``runner`` (jobs in this process,
spawned workers or Ray, one writer), ``bench`` (``driveopt bench``), ``summary`` (rates with Wilson intervals,
speeds, times; CSV, Markdown, plot), ``collect`` (``driveopt collect``: the expert's demonstrations),
``prior_metrics`` (offline metrics of a prior's first batch on held-out demonstrations; its command line is
``python -m driveopt.experiments.prior_metrics``), ``trace_episode`` (``driveopt trace-episode``: one bench episode
replayed step by step) and ``closed_loop_ab`` (``driveopt closed-loop-ab``: the same episodes under two source trees,
identical or not)."""
