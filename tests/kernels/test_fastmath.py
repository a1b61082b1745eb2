"""The vectorisable elementary functions of ``kernels/_fastmath.py`` against extended
precision, and their coefficients derived again."""

from __future__ import annotations

import math
from decimal import Decimal, getcontext
from fractions import Fraction

import numpy as np
import pytest
from numba import njit

from margtrack.kernels import _fastmath

pytestmark = pytest.mark.kernel


@njit(cache=True)
def _asin_all(xs, out):
    for i in range(xs.shape[0]):
        out[i] = _fastmath.asin(xs[i])


def _asin(xs: np.ndarray) -> np.ndarray:
    out = np.empty_like(xs)
    _asin_all(xs, out)
    return out


def _ulps(got: np.ndarray, xs: np.ndarray) -> np.ndarray:
    """|got - asin(xs)| in units of the last place of the correctly rounded asin(xs) (from
    the 64-bit-mantissa long double, rounded to double)."""
    ref = np.arcsin(xs.astype(np.longdouble)).astype(np.float64)
    return np.abs(got - ref) / np.spacing(np.abs(ref))


def test_asin_is_within_two_ulp_on_all_of_its_domain() -> None:
    rng = np.random.default_rng(5)
    xs = np.concatenate([
        rng.uniform(-1.0, 1.0, 400_000),
        np.linspace(-1.0, 1.0, 200_001),
        rng.uniform(0.49, 0.51, 50_000),  # where the two forms meet
        1.0 - np.logspace(-16, 0, 5_000),  # towards ±1
        -np.logspace(-300, 0, 5_000),  # tiny to 1
    ])
    ulps = _ulps(_asin(xs), xs)
    assert ulps.max() <= 2.0, xs[np.argmax(ulps)]
    assert np.mean(ulps == 0.0) > 0.75  # most correctly rounded


def test_asin_special_values() -> None:
    xs = np.array([0.0, -0.0, 1.0, -1.0, 0.5, -0.5, 1e-300, np.nextafter(1.0, 2.0), -1.5,
                   np.nan, np.inf])
    with np.errstate(invalid="ignore"):  # (numpy scalars when the JIT is off: inf - inf)
        got = _asin(xs)
    np.testing.assert_array_equal(got[:4], [0.0, -0.0, math.pi / 2, -math.pi / 2])
    assert math.copysign(1.0, got[1]) == -1.0  # the sign of zero kept
    assert _ulps(got[4:6], xs[4:6]).max() <= 1.0  # ±π/6
    assert got[6] == 1e-300
    assert np.isnan(got[7:]).all()  # outside [-1, 1], nan and inf: nan


def _chebyshev_fit_of_asin_r(degree: int) -> list[float]:
    """R(z) = (asin(√z) - √z) / (z √z) = Σ_{n>=1} c_n z^(n-1), c_n = (2n)! / (4^n (n!)² (2n+1))
    (asin's Maclaurin series), interpolated at the Chebyshev nodes of [0, 1/4] and written as
    monomials in z, in 50-digit arithmetic; rounded to doubles at the end."""
    getcontext().prec = 50
    terms = [Fraction(math.factorial(2 * n), 4**n * math.factorial(n) ** 2 * (2 * n + 1))
             for n in range(1, 90)]  # c_90 (1/4)^89: far below 1e-50
    c = [Decimal(f.numerator) / Decimal(f.denominator) for f in terms]

    def r_of(z: Decimal) -> Decimal:
        acc = Decimal(0)
        for cn in reversed(c):
            acc = acc * z + cn
        return acc

    pi = Decimal("3.14159265358979323846264338327950288419716939937510")

    def cos(x: Decimal) -> Decimal:
        total, term, k = Decimal(1), Decimal(1), 0
        while abs(term) > Decimal(10) ** -48:
            k += 2
            term *= -x * x / (k * (k - 1))
            total += term
        return total

    n = degree + 1
    nodes = [Decimal("0.125") + Decimal("0.125") * cos(pi * (k + Decimal("0.5")) / n)
             for k in range(n)]
    values = [r_of(z) for z in nodes]
    cheb = [sum(values[k] * cos(pi * j * (k + Decimal("0.5")) / n) for k in range(n)) * 2 / n
            for j in range(n)]
    cheb[0] /= 2
    # Chebyshev polynomials of t as monomials, then t = 8 z - 1
    t_polys = [[Decimal(1)], [Decimal(0), Decimal(1)]]
    for _ in range(2, n):
        new = [Decimal(0)] + [2 * v for v in t_polys[-1]]
        for i, v in enumerate(t_polys[-2]):
            new[i] -= v
        t_polys.append(new)
    in_t = [sum(cheb[j] * t_polys[j][i] for j in range(i, n)) for i in range(n)]
    in_z = [Decimal(0)] * n
    for i, v in enumerate(in_t):
        for k in range(i + 1):
            in_z[k] += v * math.comb(i, k) * Decimal(8) ** k * (-1) ** (i - k)
    return [float(v) for v in in_z]


def test_asin_coefficients_are_the_chebyshev_fit_of_its_series() -> None:
    assert list(_fastmath.ASIN_R) == _chebyshev_fit_of_asin_r(12)
    # and the series itself where it starts: 1/6, 3/40
    assert _fastmath.ASIN_R[0] == pytest.approx(1 / 6, rel=1e-15)
    assert _fastmath.ASIN_R[1] == pytest.approx(3 / 40, rel=1e-12)
