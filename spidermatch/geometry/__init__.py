"""Triangle meshes and what is computed on one mesh alone.

Reading and validation, spectral operators, geodesics, points on a surface, decimation,
descriptors, topology and cut copies.
"""
