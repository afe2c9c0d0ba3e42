"""Batch runs of `tetweave encode` / `decode` / `bench`: many files, local worker processes or a Ray cluster.

    inputs.py     which files (files, directories, @lists), where their outputs go, output-path checks
    work.py       what a worker does with one file (`encode_file`, `decode_file`; `EncodeOptions`)
    executors.py  where workers run: `LocalExecutor` (process pool), `RayExecutor`; a dead worker is retried once
    manifest.py   DIR/manifest.jsonl: one record per input and run; what a re-run skips
    batch.py      the driver: skip or run, write outputs atomically, record, progress, summary

Nothing here imports torch at import time: the decode path must run where torch is not installed.
"""
