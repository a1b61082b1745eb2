"""Elementary functions the compiler can vectorise: no library call, no branch.

A call to libm inside a loop over sensors (``kernels/contract_lanes.py``) is made once per
lane, scalar: ``math.asin`` in the screening cost 12 ns per sensor sample there, as much
as the rest of the field check. These are polynomials and selects instead, a few ulp
from the correctly rounded value, in the serial path as well as in lockstep (so both keep
giving the same results, bit for bit).
"""

from __future__ import annotations

import math

from margtrack.kernels.jit import njit

#: R(z) = (asin(√z) - √z) / (z √z) on [0, 1/4], as the polynomial Σ ASIN_R[k] z^k: the
#: Chebyshev interpolant of degree 12, computed from asin's Maclaurin series in 50-digit
#: arithmetic (``tests/kernels/test_fastmath.py`` derives it again)
ASIN_R = (
    0.16666666666666669, 0.07499999999998433, 0.04464285714635543, 0.030381944138531247,
    0.02237217294214989, 0.017352392720869973, 0.013971212973552933, 0.011479177415184906,
    0.01032281435018578, 0.005457506718640358, 0.01740087944269402, -0.014851887071247204,
    0.028757851367421566,
)
_PIO2_HI = 1.5707963267948966  # π/2 rounded to double
_PIO2_LO = 6.123233995736766e-17  # π/2 - _PIO2_HI


@njit(cache=True, inline="always")
def _asin_r(z):
    """R(z) of :data:`ASIN_R` (Horner)."""
    c = ASIN_R
    p = c[12]
    p = p * z + c[11]
    p = p * z + c[10]
    p = p * z + c[9]
    p = p * z + c[8]
    p = p * z + c[7]
    p = p * z + c[6]
    p = p * z + c[5]
    p = p * z + c[4]
    p = p * z + c[3]
    p = p * z + c[2]
    p = p * z + c[1]
    return p * z + c[0]


@njit(cache=True, inline="always")
def asin(x):
    """arcsin(x), rad, for x in [-1, 1] (nan outside, and for nan), within 2 ulp.

    |x| <= 1/2: ``x + x z R(z)`` with z = x²; above: ``π/2 - 2 asin(s)`` with
    s = √((1 - |x|) / 2) (the half-angle identity; 1 - |x| is exact there), the same
    polynomial on s. Both arguments are formed and one is selected, so the compiler needs
    no branch.
    """
    ax = abs(x)
    big = ax > 0.5
    z = (1.0 - ax) * 0.5 if big else x * x
    # (abs: z >= 0 wherever it is used; it lets LLVM take the sqrt instruction, libm's
    # sqrt sets errno for a negative argument)
    y = math.sqrt(abs(z)) if big else ax
    r = y + y * z * _asin_r(z)
    r = _PIO2_HI - (2.0 * r - _PIO2_LO) if big else r
    r = r if ax <= 1.0 else math.nan  # (nan for nan too: the comparison is false)
    return math.copysign(r, x)
