"""The encoder's fit: targets -> initialization -> losses -> optimization loop -> quantization-aware finish.

Modules: `targets` (renders of the input), `initialize` (SDF start), `losses` (image and grid terms),
`surface_loss` (3-D Chamfer term), `resample` (error-driven point relocation), `loop` (schedules and the training
loop). Everything here uses torch; the decoder never imports this package.
"""
