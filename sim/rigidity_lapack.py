"""The two LAPACK routines of the distributed eigen-estimate, callable from numba-compiled code.

:func:`onboard.estimation.distributed_eigen.ritz` calls scipy's ``dgesv`` and ``dsyevd``
(``scipy.linalg.lapack``). numba's ``np.linalg.solve`` and ``np.linalg.eigh`` raise on a
singular matrix (the one-agent ``T^T T`` of the first round is) and read the lower triangle,
where scipy's ``dsyevd`` reads the upper one. The compiled engine therefore calls the *same*
routines of the same library (``scipy.linalg.cython_lapack``) with the same arguments, through
symbols registered with LLVM by name (so the compiled code can be cached): both engines get the
same bits from the Ritz problem.
"""

from __future__ import annotations

import llvmlite.binding as llvm
import numpy as np
from numba import njit, types
from numba.extending import get_cython_function_address

_VP = types.voidptr
for _name in ("dgesv", "dsyevd"):
    llvm.add_symbol(
        "bearingflock_" + _name,
        get_cython_function_address("scipy.linalg.cython_lapack", _name),
    )
_dgesv = types.ExternalFunction("bearingflock_dgesv", types.void(*[_VP] * 8))
_dsyevd = types.ExternalFunction("bearingflock_dsyevd", types.void(*[_VP] * 11))


@njit(cache=True)
def dgesv(a, b):
    """``scipy.linalg.lapack.dgesv(a, b)``'s ``(lu, x, info)``: ``a`` ``(n, n)``, ``b`` ``(n, k)``
    (``lu`` transposed: its diagonal, the pivots, is what callers read)."""
    n = a.shape[0]
    k = b.shape[1]
    af = np.ascontiguousarray(a.T)  # C order of a^T = Fortran order of a
    bf = np.ascontiguousarray(b.T)
    ints = np.empty(3, np.int32)
    ints[0] = n
    ints[1] = k
    ints[2] = 0
    ipiv = np.empty(n, np.int32)
    _dgesv(
        ints[0:1].ctypes,
        ints[1:2].ctypes,
        af.ctypes,
        ints[0:1].ctypes,
        ipiv.ctypes,
        bf.ctypes,
        ints[0:1].ctypes,
        ints[2:3].ctypes,
    )
    return af, np.ascontiguousarray(bf.T), ints[2]


@njit(cache=True)
def dsyevd(a):
    """``scipy.linalg.lapack.dsyevd(a)``'s ``(w, v, info)`` (upper triangle, eigenvectors)."""
    n = a.shape[0]
    af = np.ascontiguousarray(a.T)
    w = np.empty(n)
    lwork = 1 + 6 * n + 2 * n * n
    liwork = 3 + 5 * n
    work = np.empty(lwork)
    iwork = np.empty(liwork, np.int32)
    ints = np.empty(4, np.int32)
    ints[0] = n
    ints[1] = lwork
    ints[2] = liwork
    ints[3] = 0
    chars = np.empty(2, np.uint8)
    chars[0] = 86  # 'V': eigenvectors too
    chars[1] = 85  # 'U': the upper triangle, as scipy's default
    _dsyevd(
        chars[0:1].ctypes,
        chars[1:2].ctypes,
        ints[0:1].ctypes,
        af.ctypes,
        ints[0:1].ctypes,
        w.ctypes,
        work.ctypes,
        ints[1:2].ctypes,
        iwork.ctypes,
        ints[2:3].ctypes,
        ints[3:4].ctypes,
    )
    return w, np.ascontiguousarray(af.T), ints[3]
