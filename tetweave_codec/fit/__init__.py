"""The encoder's fit: prepared input -> initialization -> main stage -> quantization-aware finish.

Modules, in the order an encode uses them:

* `prepared`: the input prepared once per encode (normalized, creases, AABB tree, surface samples, metrics'
  reference samples, rim), shared by every fit and every rate-control candidate.
* `config`: schedules (the `--quality` presets), loss weights, step sizes, quantization, `FitConfig`.
* `features`: sharp creases and corners of the input, and grid points placed around them.
* `initialize`: the SDF start (points in a shell around the input, s its signed distance).
* `grid`: the grid layout's points (the cells of a lattice in a band around the input), none placed by the fit.
* `loop`: the main stage (schedules, resampling events, the training loop; `fit_main`).
* `step`: one optimization step shared by every stage (`FitContext`, `Params`, triangulation, extraction, loss).
* `surface_loss`: the 3-D Chamfer and normal terms against the input.
* `losses`: the image terms and the TetWeave regularizers (fairness, ODT, sign).
* `targets`: renders of the input, for the image terms (off by default: config.Weights).
* `resample`: error-driven resampling of the points (importance grids).
* `relocate`: which points a resampling moves.
* `optim`: Adam and deterministic kernels.
* `finish`: points fixed to the container's grid, one triangulation as the decoder's, the late stage on s and c.
* `holes`: which faces of a decoded closed surface cap an open input's holes (`--holes keep`).

`loop`, `step`, `finish`, `surface_loss`, `losses`, `resample`, `optim` and `targets` use torch (the others numpy
only); the decoder never imports this package.
"""
