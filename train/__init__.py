"""Unsupervised training of DiffusionNet features (Cao et al. 2023 objective) on the CPU.

Modules: :mod:`train.config` (typed settings), :mod:`train.data` (split, resampling,
precomputed inputs, validation metric), :mod:`train.losses` (objective),
:mod:`train.loop` (optimisation, checkpoints, resume) and :mod:`train.cli`
(the ``spidermatch-train`` Hydra entry point).
"""
