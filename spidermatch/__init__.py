"""spidermatch: globally optimal, geometrically consistent 3D shape matching (SpiderMatch)."""

__version__ = "0.1.0"
