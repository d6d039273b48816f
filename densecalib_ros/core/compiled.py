"""Compiled (numba) kernels: the one decorator they share.

Where an inner loop is many small dependent steps per element (a patch's Gauss-Newton, a point's
share of the reduced camera system), numpy either loops in Python or makes many passes over
arrays far larger than the cache; a compiled loop keeps the work in registers and cache."""
from __future__ import annotations

from numba import njit


def compiled(**options):
    """numba.njit without the GIL (callers may run kernels on threads), with numba's on-disk
    cache where it finds a writable cache directory (beside the module or the user's cache
    directory): compiling takes seconds, loading a fraction of one. Where there is none (a
    read-only install without a home directory) each process compiles for itself."""
    def decorate(fn):
        try:
            return njit(cache=True, nogil=True, **options)(fn)
        except RuntimeError:  # numba: "cannot cache function ...: no locator available"
            return njit(nogil=True, **options)(fn)
    return decorate
