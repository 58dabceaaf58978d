"""The command-line application: Hydra entry points, config translation, datasets, resuming.

Nothing in the library imports this package.
"""
