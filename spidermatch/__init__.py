"""spidermatch: globally optimal, geometrically consistent 3D shape matching (SpiderMatch).

``from spidermatch import match`` is the Python entry point (see :mod:`spidermatch.api`);
it and the other names below are imported on first use, so ``import spidermatch`` stays light.
"""

__version__ = "0.1.0"

_LAZY = {
    "match": "spidermatch.api",
    "Matching": "spidermatch.api",
    "load_mesh": "spidermatch.geometry.io",
    "Mesh": "spidermatch.geometry.mesh",
    "MeshError": "spidermatch.geometry.mesh",
    "MatchSettings": "spidermatch.pipeline",
    "SolverOptions": "spidermatch.solve.types",
    "DenseSettings": "spidermatch.dense.settings",
    "MatchError": "spidermatch.pipeline",
    "OptionError": "spidermatch.validate",
}

__all__ = ["__version__", *_LAZY]


def __getattr__(name: str):
    """Import the public names of :data:`_LAZY` on first access."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'spidermatch' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(_LAZY))
