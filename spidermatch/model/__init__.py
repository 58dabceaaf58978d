"""The SpiderMatch model of a pair.

The SpiderCurve, the product graph, its costs, the ILP (full and lazy) and the
correspondence read back from a solution.
"""
