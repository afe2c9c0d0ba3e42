"""Maintained benchmark scripts (speed, rate control, bitstream, entropy coding, fuzzing, batch throughput), each
run as `python -m tetweave_codec.benchmarks.NAME`. The library of `tetweave bench` lives in tetweave_codec.bench.

Installed as tetweave_codec.benchmarks.
"""
