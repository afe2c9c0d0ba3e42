"""Benchmarks: the batch comparison against Draco (`tetweave bench`) and speed scripts (installed as tetweave_codec.benchmarks)."""
