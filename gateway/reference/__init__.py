"""Numpy and Pinocchio references of the compiled kernels, used by the tests and the start-up check only.

The decision path never imports this package (an import contract checks it): :mod:`gateway.kernels` computes
the same quantities compiled; the tests hold the two equal on seeded random inputs.
"""

__all__ = [
    "iso15066",
    "kinematics",
    "separation",
]
