"""Quality of a map.

Geodesic errors against ground truth, tears and flips, and a verdict without ground truth.
"""
