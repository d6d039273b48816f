"""The products of the descriptor distance matrix (matching/sift.py) by oneDNN, with inputs that
keep the float32 result to the bit even where oneDNN computes in bfloat16.

numpy's BLAS (OpenBLAS, its Haswell kernel on this AMD CPU) runs the product at about 100
GFLOP/s a core; oneDNN's AVX-512 matmul (brg_matmul:avx512_core in ONEDNN_VERBOSE) 1.7x
that on a block of asift's tiles (a whole pair 1.45-1.6x), the same float32 sums. torch hands
a float32 product to oneDNN only where its matmul precision allows bfloat16
(torch.backends.mkldnn.matmul.fp32_precision; its default, MKL, runs at about numpy's speed on
this CPU), and oneDNN may then compute in bfloat16 (CPUs with
AMX or bf16 kernels; on this one it kept float32). The inputs are made so that this changes
nothing: OpenCV's SIFT descriptors are integers 0-255, which bfloat16 holds exactly (8
significant bits), as it holds -2 x one of them and each base-256 digit of a squared norm times
its place value (norm_parts). A product of two such values is exact in float32, and every
partial sum of a distance (|r|^2 + |c|^2 - 2 r.c: integers below 2^24) is too, in any order.
So the distances, and the matches, are those of numpy's product. RootSIFT's descriptors are not
integers and stay with numpy.
"""
from __future__ import annotations

import contextlib
from typing import Callable, Iterator, Optional

import numpy as np

# Squared norms below this are integers whose three base-256 digits bfloat16 holds exactly, and
# whose sums with a product's terms stay below float32's 2^24 exact integers.
EXACT_BELOW = 2 ** 22

Product = Callable[[np.ndarray, int, int, np.ndarray], None]


def integer_descriptors(desc: np.ndarray) -> bool:
    """Whether every value is an integer in 0-255 (OpenCV's SIFT; RootSIFT's are not)."""
    return bool(desc.size == 0 or (desc.min() >= 0 and desc.max() <= 255
                                   and np.array_equal(desc, np.round(desc))))


def norm_parts(sq_norms: np.ndarray) -> np.ndarray:
    """float32 (K, 3) summing to each squared norm: its base-256 digits times their place values
    where the norms are integers below EXACT_BELOW (each part exact in bfloat16), else the norm
    and two zeros."""
    sq = np.asarray(sq_norms, np.float64)
    parts = np.zeros((len(sq), 3), np.float32)
    if len(sq) and np.all(sq == np.round(sq)) and sq.max() < EXACT_BELOW:
        n = sq.astype(np.int64)
        parts[:, 0] = (n >> 16) << 16
        parts[:, 1] = ((n >> 8) & 255) << 8
        parts[:, 2] = n & 255
    else:
        parts[:, 0] = sq
    return parts


def numpy_product(cols: np.ndarray) -> Product:
    """out = rows @ cols[c0:c1].T in float32 (numpy's BLAS)."""
    def product(rows: np.ndarray, c0: int, c1: int, out: np.ndarray) -> None:
        np.matmul(rows, cols[c0:c1].T, out=out)
    return product


def onednn_product(cols: np.ndarray) -> Product:
    """The same product by oneDNN, under onednn_products (module docstring): only for rows and
    columns of integer descriptors and norm_parts."""
    import torch

    cols_t = torch.from_numpy(cols)

    def product(rows: np.ndarray, c0: int, c1: int, out: np.ndarray) -> None:
        torch.mm(torch.from_numpy(rows), cols_t[c0:c1].T, out=torch.from_numpy(out))
    return product


@contextlib.contextmanager
def onednn_products(threads_per_product: int) -> Iterator[Optional[bool]]:
    """Within: torch's float32 matrix products go to oneDNN, which may take their inputs as
    bfloat16 (exact for the products above), each on `threads_per_product` threads; both torch
    settings are put back after. Yields whether torch is there (None: use numpy_product)."""
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a pinned dependency
        yield None
        return
    precision = torch.backends.mkldnn.matmul.fp32_precision
    try:
        torch.backends.mkldnn.matmul.fp32_precision = "bf16"
    except RuntimeError:  # a torch that refuses it here: numpy's products, the same distances
        yield None
        return
    threads = torch.get_num_threads()
    torch.set_num_threads(max(1, threads_per_product))
    try:
        yield True
    finally:
        torch.backends.mkldnn.matmul.fp32_precision = precision
        torch.set_num_threads(threads)
