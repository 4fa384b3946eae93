"""Experiments: many closed-loop episodes, resumably. ``store`` (append-only JSONL records and the
job key), ``runner`` (jobs in this process, spawned workers or Ray, one writer), ``bench``
(``driveopt bench``) and ``summary`` (rates with Wilson intervals, speeds, times; CSV, Markdown, plot)."""
