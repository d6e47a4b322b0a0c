"""Named FitSettings overrides for ``teeth fit --preset`` and the Blender fit panel's Settings.

Plain data without imports, so that the CLI's ``--help`` can show them without loading the renderer.
Explicit command-line flags win over a preset's values.

"acceptance" is the issue's parameter-recovery fit (``benchmarks/teeth.py`` adds its 2 render
processes): 6 random lights per iteration, pass A at 32 spp and pass B at 4 spp, the L2 loss of
8 x 8 box-filtered images, Adam for 80 iterations, then Gauss-Newton steps for the materials with
the pooled matrix of 8 passes, damping 0.01 and a divergence guard that only reacts to a doubled
loss, while the dentin coefficients keep Adam; 300 iterations, and the result is the mean of the
last 30 % of the iterates, over which the coefficients' random walk along their valley averages out
(README, "Why Adam stalls").
"""

from __future__ import annotations

FIT_PRESETS: dict[str, dict] = {
    "thesis": {},
    "acceptance": {"iterations": 300, "lr": 0.04, "lr_decay": 0.01, "spp": 4, "image_spp": 32,
                   "lights_per_iteration": 6, "loss_block": 8, "optimiser": "gauss-newton", "gn_start": 80,
                   "gn_every": 40, "gn_lr": 0.5, "gn_estimator": "pooled", "gn_passes": 8, "gn_damping": 0.01,
                   "gn_c_lr": 1.0, "gn_guard_rise": 1.0, "average_tail": 0.3},
}
