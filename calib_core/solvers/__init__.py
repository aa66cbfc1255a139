"""Solvers, one module per procedure (six_position, multi_position, integral, ...)."""
