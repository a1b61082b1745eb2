"""The vectorisable elementary functions of ``estimator/fastmath.py`` against extended
precision, and their coefficients derived again."""

from __future__ import annotations

import math
from decimal import Decimal, getcontext
from fractions import Fraction

import numpy as np
import pytest
from numba import njit

from margtrack.estimator import fastmath as _fastmath

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


def _chebyshev_fit(series: list[Fraction], b: Decimal, degree: int) -> list[float]:
    """The function Σ series[n] z^n interpolated at the degree + 1 Chebyshev nodes of [0, b]
    and written as monomials in z, in 60-digit arithmetic; rounded to doubles at the end."""
    getcontext().prec = 60
    c = [Decimal(f.numerator) / Decimal(f.denominator) for f in series]

    def f(z: Decimal) -> Decimal:
        acc = Decimal(0)
        for cn in reversed(c):
            acc = acc * z + cn
        return acc

    def cos(x: Decimal) -> Decimal:
        total, term, k = Decimal(1), Decimal(1), 0
        while abs(term) > Decimal(10) ** -58:
            k += 2
            term *= -x * x / (k * (k - 1))
            total += term
        return total

    n, h = degree + 1, b / 2
    nodes = [h + h * cos(_PI * (k + Decimal("0.5")) / n) for k in range(n)]
    values = [f(z) for z in nodes]
    cheb = [sum(values[k] * cos(_PI * j * (k + Decimal("0.5")) / n) for k in range(n)) * 2 / n
            for j in range(n)]
    cheb[0] /= 2
    # Chebyshev polynomials of t as monomials, then t = z / h - 1
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
            in_z[k] += v * math.comb(i, k) / h**k * (-1) ** (i - k)
    return [float(v) for v in in_z]


_PI = Decimal("3.14159265358979323846264338327950288419716939937510582097494459")


def test_coefficients_are_the_chebyshev_fits_of_the_series() -> None:
    """Each tuple from its function's Maclaurin series (the terms after the first one or
    two, over the power of z the polynomial multiplies)."""
    getcontext().prec = 60
    asin = [Fraction(math.factorial(2 * n), 4**n * math.factorial(n) ** 2 * (2 * n + 1))
            for n in range(1, 90)]  # c_90 (1/4)^89: far below 1e-50
    sin = [Fraction((-1) ** n, math.factorial(2 * n + 1)) for n in range(1, 40)]
    cos = [Fraction((-1) ** n, math.factorial(2 * n)) for n in range(2, 40)]
    atan = [Fraction((-1) ** n, 2 * n + 1) for n in range(1, 400)]  # 0.1716^400: nothing
    quarter_pi_squared = (_PI / 4) ** 2
    tan_pi8_squared = (Decimal(2).sqrt() - 1) ** 2
    assert list(_fastmath.ASIN_R) == _chebyshev_fit(asin, Decimal("0.25"), 12)
    assert list(_fastmath.SIN_S) == _chebyshev_fit(sin, quarter_pi_squared, 5)
    assert list(_fastmath.COS_C) == _chebyshev_fit(cos, quarter_pi_squared, 5)
    assert list(_fastmath.ATAN_A) == _chebyshev_fit(atan, tan_pi8_squared, 10)
    # and the series where they start: 1/6, -1/6, 1/24, -1/3
    assert _fastmath.ASIN_R[0] == pytest.approx(1 / 6, rel=1e-15)
    assert (_fastmath.SIN_S[0], _fastmath.COS_C[0], _fastmath.ATAN_A[0]) == (-1 / 6, 1 / 24, -1 / 3)


def test_pi_constants_are_pi() -> None:
    f = _fastmath
    for hi, lo, value in ((f._PI_HI, f._PI_LO, _PI), (f._PIO2_HI, f._PIO2_LO, _PI / 2),
                          (f._PIO4_HI, f._PIO4_LO, _PI / 4)):
        assert abs(Decimal(hi) + Decimal(lo) - value) < Decimal(10) ** -32
    pieces = (Decimal(f._P1), Decimal(f._P2), Decimal(f._P3))
    assert abs(sum(pieces) - _PI / 2) < Decimal(10) ** -36
    for piece in pieces[:2]:  # 33 bits: k times it exact for |k| < 2^20
        mantissa, _ = math.frexp(float(piece))
        assert (mantissa * 2**33).is_integer()


@njit(cache=True)
def _sincos_all(xs, sin_out, cos_out):
    for i in range(xs.shape[0]):
        sin_out[i], cos_out[i] = _fastmath.sincos(xs[i])


@njit(cache=True)
def _atan2_all(ys, xs, out):
    for i in range(xs.shape[0]):
        out[i] = _fastmath.atan2(ys[i], xs[i])


def _ulps_of(got: np.ndarray, exact: np.ndarray) -> np.ndarray:
    """|got - exact| in ulp of the correctly rounded value (exact: long double)."""
    ref = exact.astype(np.float64)
    return np.abs(got - ref) / np.spacing(np.abs(ref))


def test_sincos_is_within_two_ulp() -> None:
    rng = np.random.default_rng(6)
    quarter = np.arange(-40, 41) * (np.pi / 4)  # the octant boundaries and around them
    xs = np.concatenate([
        rng.uniform(-7.0, 7.0, 300_000), rng.uniform(-1e-3, 1e-3, 20_000),
        rng.uniform(-1e5, 1e5, 50_000), quarter, np.nextafter(quarter, 99.0),
        np.nextafter(quarter, -99.0), np.logspace(-300, 6, 2_000),
    ])
    sin_x, cos_x = np.empty_like(xs), np.empty_like(xs)
    _sincos_all(xs, sin_x, cos_x)
    exact = xs.astype(np.longdouble)
    assert _ulps_of(sin_x, np.sin(exact)).max() <= 2.0
    assert _ulps_of(cos_x, np.cos(exact)).max() <= 2.0
    assert np.all(sin_x * sin_x + cos_x * cos_x == pytest.approx(1.0, abs=5e-16))
    specials = np.array([0.0, -0.0, np.nan, np.inf])
    sin_s, cos_s = np.empty(4), np.empty(4)
    with np.errstate(invalid="ignore"):  # (numpy scalars when the JIT is off)
        _sincos_all(specials, sin_s, cos_s)
    assert (sin_s[0], cos_s[0], sin_s[1], cos_s[1]) == (0.0, 1.0, 0.0, 1.0)
    assert np.isnan(sin_s[2:]).all() and np.isnan(cos_s[2:]).all()


def test_atan2_is_within_three_ulp_and_takes_the_edge_cases_of_math_atan2() -> None:
    rng = np.random.default_rng(7)
    n = 300_000
    ys = rng.normal(size=n) * np.exp(rng.uniform(-20.0, 20.0, n))
    xs = rng.normal(size=n) * np.exp(rng.uniform(-20.0, 20.0, n))
    xs[:1000] = ys[:1000] * rng.choice([-1.0, 1.0], 1000)  # the diagonals
    got = np.empty(n)
    _atan2_all(ys, xs, got)
    assert _ulps_of(got, np.arctan2(ys.astype(np.longdouble), xs.astype(np.longdouble))).max() <= 3
    values = [0.0, -0.0, 1.0, -1.0, 1e-300, np.inf, -np.inf, np.nan]
    grid_y, grid_x = (a.ravel() for a in np.meshgrid(values, values))
    edge = np.empty(grid_x.size)
    with np.errstate(invalid="ignore", divide="ignore"):  # (numpy scalars, JIT off)
        _atan2_all(grid_y, grid_x, edge)
    expected = np.array([math.atan2(y, x) for y, x in zip(grid_y, grid_x, strict=True)])
    numbers = ~np.isnan(expected)
    np.testing.assert_array_equal(np.signbit(edge[numbers]), np.signbit(expected[numbers]))
    np.testing.assert_allclose(edge, expected, rtol=4e-16, atol=0.0)
