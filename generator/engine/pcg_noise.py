"""The flights' noise drawn in compiled code: numpy's PCG64 and standard-normal ziggurat, value for value.

Each flight draws its normals from its own ``numpy.random.Generator`` (PCG64). numpy fills them at
about 12-16 ns a value (a call through the bit generator's function pointer per value); the same
generator stepped inline here (128-bit LCG, XSL-RR output) feeding the same ziggurat (numpy's
``random_standard_normal``, with its tables) gives the same doubles at a few ns a value.
A flight's state is copied out of its Generator once (:func:`pcg_states`) and advanced in
``states`` only: the Generator objects are not advanced.
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, prange, types
from numba.extending import intrinsic
from numba.np.random._constants import fi_double, ki_double, wi_double, ziggurat_nor_inv_r, ziggurat_nor_r

_MULT_HI = np.uint64(2549297995355413924)  # PCG64's 128-bit multiplier (numpy's PCG_DEFAULT_MULTIPLIER)
_MULT_LO = np.uint64(4865540595714422341)
_KI = np.ascontiguousarray(ki_double, dtype=np.uint64)
_WI = np.ascontiguousarray(wi_double, dtype=np.float64)
#: wi and -wi: the sign bit picks the half (no branch on a coin flip); -(a * b) == a * -b exactly
_WI_SIGNED = np.concatenate([_WI, -_WI])
_FI = np.ascontiguousarray(fi_double, dtype=np.float64)
_NOR_R = float(ziggurat_nor_r)
_NOR_INV_R = float(ziggurat_nor_inv_r)
_TO_DOUBLE = 1.0 / 9007199254740992.0


@intrinsic
def _pcg_step(typingctx, shi, slo, ihi, ilo, mhi, mlo):
    """(state * mult + inc) mod 2**128 and the XSL-RR output of the new state: (hi, lo, output)."""
    u64 = types.uint64
    sig = types.UniTuple(u64, 3)(u64, u64, u64, u64, u64, u64)

    def codegen(context, builder, signature, args):
        i64, i128 = ir.IntType(64), ir.IntType(128)
        c64 = ir.Constant(i128, 64)

        def join(hi, lo):
            return builder.or_(builder.shl(builder.zext(hi, i128), c64), builder.zext(lo, i128))

        state = builder.add(builder.mul(join(args[0], args[1]), join(args[4], args[5])), join(args[2], args[3]))
        hi = builder.trunc(builder.lshr(state, c64), i64)
        lo = builder.trunc(state, i64)
        rot = builder.lshr(hi, ir.Constant(i64, 58))
        x = builder.xor(hi, lo)
        back = builder.and_(builder.sub(ir.Constant(i64, 64), rot), ir.Constant(i64, 63))
        out = builder.or_(builder.lshr(x, rot), builder.shl(x, back))  # rotate right by rot
        return context.make_tuple(builder, signature.return_type, (hi, lo, out))

    return sig, codegen


@njit(inline="always")
def _next(shi, slo, ihi, ilo):
    """The next 64 random bits: (output, state high, state low)."""
    hi, lo, out = _pcg_step(shi, slo, ihi, ilo, _MULT_HI, _MULT_LO)
    return out, hi, lo


@njit(inline="always")
def _to_double(bits):
    return np.float64(bits >> np.uint64(11)) * _TO_DOUBLE


@njit(nogil=True, forceinline=True, cache=True)
def _normal(shi, slo, ihi, ilo):
    """One standard normal as numpy's random_standard_normal (ziggurat) draws it: (value, state high, low).

    The state is passed and returned as values (not through an array), so that it stays in registers."""
    while True:
        r, shi, slo = _next(shi, slo, ihi, ilo)
        idx = r & np.uint64(0xFF)
        rabs = (r >> np.uint64(9)) & np.uint64(0x000FFFFFFFFFFFFF)
        x = np.float64(rabs) * _WI_SIGNED[r & np.uint64(0x1FF)]  # bit 8 of r: the sign
        if rabs < _KI[idx]:
            return x, shi, slo
        if idx == 0:
            while True:
                u, shi, slo = _next(shi, slo, ihi, ilo)
                xx = -_NOR_INV_R * np.log1p(-_to_double(u))
                u, shi, slo = _next(shi, slo, ihi, ilo)
                yy = -np.log1p(-_to_double(u))
                if yy + yy > xx * xx:
                    if (rabs >> np.uint64(8)) & np.uint64(1):
                        return -(_NOR_R + xx), shi, slo
                    return _NOR_R + xx, shi, slo
        else:
            u, shi, slo = _next(shi, slo, ihi, ilo)
            if (_FI[idx - np.uint64(1)] - _FI[idx]) * _to_double(u) + _FI[idx] < np.exp(-0.5 * x * x):
                return x, shi, slo


@njit(nogil=True, forceinline=True, cache=True)
def fill_one(states, i, o):
    """``o`` (steps, dim) <- flight ``i``'s next normals, in order."""
    st = states[i]
    shi, slo, ihi, ilo = st[0], st[1], st[2], st[3]
    for k in range(o.shape[0]):
        for d in range(o.shape[1]):
            o[k, d], shi, slo = _normal(shi, slo, ihi, ilo)
    st[0] = shi
    st[1] = slo


@njit(nogil=True, cache=True)
def fill_rows(states, rows, out):
    """``out[j]`` (steps, dim) <- flight ``rows[j]``'s next normals, in order (``states``: (N, 4) uint64)."""
    for j in range(rows.shape[0]):
        fill_one(states, rows[j], out[j])


@njit(nogil=True, parallel=True, cache=True)
def fill_rows_parallel(states, rows, out):
    """fill_rows over the kernel's worker threads: each flight's generator is stepped by one thread,
    in order, so the values do not depend on the threads (the same bytes as fill_rows)."""
    for j in prange(rows.shape[0]):
        fill_one(states, rows[j], out[j])


def pcg_states(rngs: list[np.random.Generator]) -> np.ndarray | None:
    """(N, 4) uint64: state high, low, increment high, low of each flight's PCG64; None if one is not PCG64."""
    out = np.empty((len(rngs), 4), dtype=np.uint64)
    mask = (1 << 64) - 1
    for i, g in enumerate(rngs):
        st = g.bit_generator.state
        if st.get("bit_generator") != "PCG64":
            return None
        s, inc = int(st["state"]["state"]), int(st["state"]["inc"])
        out[i] = (s >> 64, s & mask, inc >> 64, inc & mask)
    return out
