"""The ground-truth realism benchmark's own parts (benchmarks/bench_realism.py): a reference
rasteriser, the synthetic scene, the ground-truth edits and their presets, the metrics.

None of it uses the project's renderer or deformer: the ground truth must not share their
mistakes. The project's landmark detector and fitter are used once, to fit the photo the head's
texture is taken from (analysis, not rendering)."""
