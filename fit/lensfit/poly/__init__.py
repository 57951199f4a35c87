"""Sparse polynomial systems and their fitting by orthogonal matching pursuit."""

from lensfit.poly.polynomial import Input, Polynomial, System, design_matrix, monomials

__all__ = ["Input", "Polynomial", "System", "design_matrix", "monomials"]
