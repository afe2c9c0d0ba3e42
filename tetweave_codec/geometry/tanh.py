"""The decoder's tanh: one fixed sequence of binary64 operations, so that every decoder computes the same bits.

Directional marching tets (formats/README.md, "Decoding" step 3) takes tanh of every SH value. A library's tanh is
not the same function everywhere: numpy's float64 tanh is an SVML-derived polynomial where the CPU has FMA
(AVX2, AVX-512, NEON) and the C library's elsewhere, and glibc 2.36's differs from both (measured on 30,000
arguments: numpy's AVX-512 loop and glibc each differ from the correctly rounded value on ~19 % of them, and from
each other on ~30 %, by one or two units in the last place). So the format fixes this algorithm (`decoder/marching.c`
`tw_tanh` computes the same sequence in C, compiled without contraction): only +, -, *, /, floor, an exact
scaling by 2^k and a sign copy, each rounded once as IEEE 754 binary64 requires on every platform.

    a = |x|;  if not a < 20: return copysign(1, x)          (tanh rounds to 1 there; NaN gives +-1 too)
    if a < 2^-27: return x                                   (tanh(x) = x - x^3/3 rounds to x)
    t = a + a
    k = floor(t * INV_LN2 + 0.5)                             (0..58)
    r = (t - k * LN2_HI) - k * LN2_LO                        (|r| <= ~ln2 / 2; the first subtraction is exact)
    q = C16;  q = q * r + C_n for n = 15, 14, ..., 2         (C_n: 1/n! rounded to binary64)
    p = r + r * (r * q)                                      (expm1(r))
    e = 2^k * p + (2^k - 1)                                  (expm1(t), 2^k exact)
    return copysign(e / (e + 2), x)                          (tanh(a) = expm1(2a) / (expm1(2a) + 2))

with the constants below (hexadecimal binary64). Error against the exact tanh: at most 2 units in the last place
(tests/test_core_geometry.py measures it against mpmath); the decoder needs determinism, not correct rounding.
"""

from __future__ import annotations

import numpy as np

INV_LN2 = float.fromhex("0x1.71547652b82fep+0")
LN2_HI = float.fromhex("0x1.62e42fefa0000p-1")  # 37 significant bits: k * LN2_HI is exact for k < 2^16
LN2_LO = float.fromhex("0x1.cf79abc9e3b3ap-40")
SATURATION = 20.0
TINY = float.fromhex("0x1p-27")
# C_n = 1/n! rounded to binary64, n = 2..16
EXPM1_COEFFS = tuple(
    float.fromhex(h)
    for h in (
        "0x1.0000000000000p-1",
        "0x1.5555555555555p-3",
        "0x1.5555555555555p-5",
        "0x1.1111111111111p-7",
        "0x1.6c16c16c16c17p-10",
        "0x1.a01a01a01a01ap-13",
        "0x1.a01a01a01a01ap-16",
        "0x1.71de3a556c734p-19",
        "0x1.27e4fb7789f5cp-22",
        "0x1.ae64567f544e4p-26",
        "0x1.1eed8eff8d898p-29",
        "0x1.6124613a86d09p-33",
        "0x1.93974a8c07c9dp-37",
        "0x1.ae7f3e733b81fp-41",
        "0x1.ae7f3e733b81fp-45",
    )
)


def tanh(x: np.ndarray) -> np.ndarray:
    """tanh of a float64 array by the sequence of the module docstring (elementwise numpy: no FMA, no BLAS)."""
    x = np.asarray(x, dtype=np.float64)
    a = np.abs(x)
    live = a < SATURATION  # False for NaN too
    a_live = np.where(live, a, 0.0)
    t = a_live + a_live
    k = np.floor(t * INV_LN2 + 0.5)
    r = (t - k * LN2_HI) - k * LN2_LO
    q = np.full_like(r, EXPM1_COEFFS[-1])
    for coeff in EXPM1_COEFFS[-2::-1]:
        q = q * r + coeff
    p = r + r * (r * q)
    scale = np.ldexp(1.0, k.astype(np.int64))
    e = scale * p + (scale - 1.0)
    y = e / (e + 2.0)
    y = np.where(a < TINY, a, y)
    return np.copysign(np.where(live, y, 1.0), x)
