"""Elementary functions the compiler can vectorise: no library call, no branch.

A call to libm inside a loop over sensors (``estimator/lockstep.py``) is made once per
lane, scalar: ``math.asin`` in the screening cost 12 ns per sensor sample there, as much
as the rest of the field check. These are polynomials and selects instead, a few ulp
from the correctly rounded value, in the serial path as well as in lockstep (so both keep
giving the same results, bit for bit).

Each polynomial is the Chebyshev interpolant, written as monomials, of the function's
Maclaurin series on the reduced interval, computed in 50-digit arithmetic
(``tests/estimator/test_fastmath.py`` derives the coefficients again and measures the
errors against long double).
"""

from __future__ import annotations

import math

import numpy as np

from margtrack.estimator.jit import njit

#: (asin(√z) - √z) / (z √z) on z in [0, 1/4], as Σ ASIN_R[k] z^k (degree 12)
ASIN_R = (
    0.16666666666666669, 0.07499999999998433, 0.04464285714635543, 0.030381944138531247,
    0.02237217294214989, 0.017352392720869973, 0.013971212973552933, 0.011479177415184906,
    0.01032281435018578, 0.005457506718640358, 0.01740087944269402, -0.014851887071247204,
    0.028757851367421566,
)
#: (sin(√z) - √z) / (z √z) on z in [0, (π/4)²] (degree 5)
SIN_S = (
    -0.16666666666666666, 0.008333333333330948, -0.00019841269836758574,
    2.755731610255244e-06, -2.5051131845003624e-08, 1.5918129294866608e-10,
)
#: (cos(√z) - 1 + z / 2) / z² on z in [0, (π/4)²] (degree 5)
COS_C = (
    0.041666666666666664, -0.0013888888888887398, 2.480158729876569e-05,
    -2.7557317271729793e-07, 2.08761462684032e-09, -1.1382632425521717e-11,
)
#: (atan(√z) - √z) / (z √z) on z in [0, tan²(π/8)] (degree 10)
ATAN_A = (
    -0.3333333333333333, 0.1999999999999552, -0.14285714284666542, 0.11111111015256361,
    -0.09090904578123903, 0.07692183190826087, -0.06664511447381948, 0.0585814891280221,
    -0.0508544973794026, 0.03923165829558719, -0.01917688711906226,
)
_PI_HI, _PI_LO = 3.141592653589793, 1.2246467991473532e-16  # π rounded, and the rest
_PIO2_HI, _PIO2_LO = 1.5707963267948966, 6.123233995736766e-17  # π/2
_PIO4_HI, _PIO4_LO = 0.7853981633974483, 3.061616997868383e-17  # π/4
_TAN_PIO8 = 0.41421356237309503  # tan(π/8) = √2 - 1
_TWO_OVER_PI = 0.6366197723675814
# π/2 in three parts of 33, 33 and 53 bits: k·_P1 and k·_P2 are exact for |k| < 2^20
_P1, _P2, _P3 = 1.5707963267341256, 6.077100506303966e-11, 2.0222662487959506e-21


@njit(cache=True, inline="always")
def _horner(c, z):
    """Σ c[k] z^k for a tuple of constants c (Horner; the loop's length is a constant, so
    LLVM unrolls it and a loop over sensors around it still vectorises)."""
    p = c[len(c) - 1]
    for k in range(len(c) - 2, -1, -1):
        p = p * z + c[k]
    return p


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
    r = y + y * z * _horner(ASIN_R, z)
    r = _PIO2_HI - (2.0 * r - _PIO2_LO) if big else r
    r = r if ax <= 1.0 else math.nan  # (nan for nan too: the comparison is false)
    return math.copysign(r, x)


@njit(cache=True, inline="always")
def sincos(x):
    """(sin x, cos x) for x in rad, within 2 ulp for |x| < 1.6e6 (2^20 π/2); beyond, the
    reduction loses accuracy (an angle there is a number's rounding anyway). sin(-0) is +0.

    x = k π/2 + r with |r| <= π/4 (Cody-Waite: π/2 in three parts), then the polynomials
    on r and the quadrant k mod 4 chosen by selects.
    """
    k = np.floor(x * _TWO_OVER_PI + 0.5)  # (a float: math.floor gives an int)
    r = ((x - k * _P1) - k * _P2) - k * _P3
    z = r * r
    s = r + r * z * _horner(SIN_S, z)
    c = 1.0 - 0.5 * z + z * z * _horner(COS_C, z)
    quadrant = k - 4.0 * np.floor(k * 0.25)  # 0, 1, 2 or 3
    sin_x = s if quadrant == 0.0 else (c if quadrant == 1.0 else (-s if quadrant == 2.0 else -c))
    cos_x = c if quadrant == 0.0 else (-s if quadrant == 1.0 else (-c if quadrant == 2.0 else s))
    finite = abs(x) < math.inf  # (inf and nan: nan)
    return (sin_x if finite else math.nan), (cos_x if finite else math.nan)


@njit(cache=True, inline="always")
def atan2(y, x):
    """The angle of (x, y) from the x axis, rad in [-π, π], as ``math.atan2`` (signed
    zeros and infinities included), within 3 ulp.

    t = min(|x|, |y|) / max(|x|, |y|) in [0, 1]; above tan(π/8), atan t = π/4 + atan u with
    u = (t - 1) / (t + 1); the polynomial on |u| <= tan(π/8); then the octant by selects.
    """
    ax, ay = abs(x), abs(y)
    hi, lo = max(ax, ay), min(ax, ay)
    # (equal: 1, also for two infinities; both zero: 0)
    t = (1.0 if ax == ay else lo / hi) if hi > 0.0 else 0.0
    big = t > _TAN_PIO8
    u = (t - 1.0) / (t + 1.0) if big else t
    z = u * u
    a = u + u * z * _horner(ATAN_A, z)
    a = _PIO4_HI + (a + _PIO4_LO) if big else a
    a = _PIO2_HI - (a - _PIO2_LO) if ay > ax else a
    a = _PI_HI - (a - _PI_LO) if math.copysign(1.0, x) < 0.0 else a
    a = a if (x == x) & (y == y) else math.nan
    return math.copysign(a, y)
