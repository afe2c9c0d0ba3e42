"""Benchmarks: the batch comparison against Draco (`tetweave bench`) and speed scripts.

Installed as tetweave_codec.benchmarks.
"""
