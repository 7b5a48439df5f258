"""Bayesian Fields: task-driven open-set semantic mapping on 3D Gaussian Splats.

The library is importable and testable with no server running; it imports no web,
queue or object-storage client (the services wrap it).
"""

__version__ = "0.1.0"
