"""`tetweave bench`: tetweave against the classical pipelines (Draco, decimation + Draco) at matched error.

methods.py: the `Method` interface, the family names and the tetweave method; baselines.py: the classical methods;
batch.py: every mesh x every method -> encode, decode, time, measure (result rows); sweep.py: the adaptive
classical sweep around the tetweave points (the default) and the full one; parallel.py: the tetweave encodes
through the runner (--jobs, --ray); report.py: results.csv, summary.md and the matched-error verdict;
pictures.py: rate-distortion plots and side-by-side renders; anchor.py: plain Draco's bytes at a given Chamfer distance
(the encoder's context line).
"""
