"""Numba-compiled inner loops of the estimators and filters (nothing else lives here).

Kernels take and fill plain float64 arrays, loop over samples (and sensors), and hold no
Python objects. Validation and allocation happen in the Python wrappers that call them.
"""
