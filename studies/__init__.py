"""Studies and comparisons.

The reduced-model study and comparison, the stability-margin map, inference, and the walker
cells that drive the simulated robot (docs/schemes.md). They may use the follower's simulated
robot; the core never imports this package, it reaches it through entry points.
"""
