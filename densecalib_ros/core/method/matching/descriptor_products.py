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

Where torch has an 8-bit integer product whose sums are exact on this CPU (AMX or VNNI:
int8_exact_here checks it), the products are int8_product's instead: the row and column
descriptors less 128 (signed 8-bit) multiplied into int32 (torch._int_mm), each distance being
that product times -2 plus a row's and a column's own terms (their squared norms, and the sums
the shift by 128 adds; Product). A quarter of the bytes in, no conversion of the inputs, and no
pass writing the terms into the tile (docs/design-notes.md, Tiles reduced in one compiled pass);
every sum is exact in int32, so the distances are those of numpy's product to the bit.
"""
from __future__ import annotations

import contextlib
import functools
from dataclasses import dataclass
from typing import Any, Callable, Iterator, Optional

import numpy as np

# Squared norms below this are integers whose three base-256 digits bfloat16 holds exactly, and
# whose sums with a product's terms stay below float32's 2^24 exact integers.
EXACT_BELOW = 2 ** 22


@dataclass(frozen=True)
class Product:
    """A tile of the distance matrix, computed in parts: distance[i, j] = row_terms(rows)[i] +
    col_terms[c0 + j] + scale x tile[i, j], where fill(rows, c0, c1, tile) writes the tile (of
    dtype) for columns c0..c1. The float products hold whole distances (terms of 0, scale 1)."""
    fill: Callable[[np.ndarray, int, int, np.ndarray], None]
    dtype: type
    scale: Any
    col_terms: np.ndarray
    row_terms: Callable[[np.ndarray], np.ndarray]


def _whole_distances(fill: Callable[[np.ndarray, int, int, np.ndarray], None],
                     cols: np.ndarray) -> Product:
    """A float32 product whose tile holds the distances themselves."""
    return Product(fill, np.float32, np.float32(1.0), np.zeros(len(cols), np.float32),
                   lambda rows: np.zeros(len(rows), np.float32))


def integer_descriptors(desc: np.ndarray) -> bool:
    """Whether every value is an integer in 0-255 (OpenCV's SIFT; RootSIFT's are not)."""
    return bool(desc.size == 0 or (desc.min() >= 0 and desc.max() <= 255
                                   and np.array_equal(desc, np.round(desc))))


def int8_exact(desc: np.ndarray) -> bool:
    """Whether int8_product's int32 sums hold these descriptors' distances: 128 values each
    (integer_descriptors must hold as well). Each product of two descriptors less 128 is within
    128^3 = 2.1e6 of zero, a squared norm under 255^2 x 128 = 8.3e6, and every term and sum of
    Product's far below int32's 2^31."""
    return bool(desc.size == 0 or desc.shape[1] == 128)


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
    """Tiles of rows @ cols[c0:c1].T in float32 (numpy's BLAS): whole distances."""
    def fill(rows: np.ndarray, c0: int, c1: int, out: np.ndarray) -> None:
        np.matmul(rows, cols[c0:c1].T, out=out)
    return _whole_distances(fill, cols)


def onednn_product(cols: np.ndarray) -> Product:
    """The same product by oneDNN, under onednn_products (module docstring): only for rows and
    columns of integer descriptors and norm_parts."""
    import torch

    cols_t = torch.from_numpy(cols)

    def fill(rows: np.ndarray, c0: int, c1: int, out: np.ndarray) -> None:
        torch.mm(torch.from_numpy(rows), cols_t[c0:c1].T, out=torch.from_numpy(out))
    return _whole_distances(fill, cols)


def int8_product(cols: np.ndarray) -> Product:
    """The distances by torch's 8-bit integer product (module docstring): only where
    int8_exact_here() and for columns of descriptors that integer_descriptors and int8_exact
    pass. Each rows array is converted once (the tiles of a block row come one after another).
    The rows and columns are _row_blocks' and _columns' (matching/sift.py): -2 x the descriptors
    and the descriptors, each followed by six values of its squared norm's parts and ones."""
    import torch

    desc_cols = cols[:, :-6]
    shifted_t = torch.from_numpy((desc_cols - 128.0).astype(np.int8)).T
    converted: list = [None, None]  # rows, as signed 8-bit less 128

    def fill(rows: np.ndarray, c0: int, c1: int, out: np.ndarray) -> None:
        if converted[0] is not rows:
            converted[:] = [rows, torch.from_numpy((rows[:, :-6] * -0.5 - 128.0).astype(np.int8))]
        torch._int_mm(converted[1], shifted_t[:, c0:c1], out=torch.from_numpy(out))
    return Product(fill, np.int32, np.int32(-2), _shifted_terms(desc_cols),
                   lambda rows: _shifted_terms(rows[:, :-6] * -0.5))


def _shifted_terms(desc: np.ndarray) -> np.ndarray:
    """Each descriptor's own term of its distances when products are taken less 128 (int8_product):
    |d|^2 - 256 sum(d - 128) - 128^3, as int32 (int8_exact bounds it). Since
    d.e = (d - 128).(e - 128) + 128 sum(d - 128) + 128 sum(e - 128) + 128^3 over 128 values,
    |d - e|^2 = these terms of d and e less 2 (d - 128).(e - 128)."""
    d = desc.astype(np.int64)
    return ((d * d).sum(axis=1) - 256 * (d - 128).sum(axis=1) - 128 ** 3).astype(np.int32)


def onednn_product_for(descriptors: list[np.ndarray]) -> Callable[[np.ndarray], Product]:
    """int8_product where int8_exact_here() and int8_exact holds for every image's descriptors
    (integer_descriptors must), else onednn_product."""
    if int8_exact_here() and all(int8_exact(d) for d in descriptors):
        return int8_product
    return onednn_product


def int8_kernel_here() -> bool:
    """Whether torch has its 8-bit integer product and this CPU an 8-bit integer dot product
    (AMX or VNNI): without one, oneDNN adds pairs of 8-bit products in saturating 16-bit lanes
    (255 x 127 twice is past 32767)."""
    try:
        import torch
        return bool(hasattr(torch, "_int_mm") and (
            torch.cpu._is_amx_tile_supported() or torch.cpu._is_vnni_supported()))
    except (ImportError, AttributeError, RuntimeError):
        return False


@functools.lru_cache(maxsize=1)
def int8_exact_here() -> bool:
    """Whether int8_kernel_here() and int8_product's distances are exact on descriptors at the
    limits of the range."""
    if not int8_kernel_here():
        return False
    try:
        rng = np.random.default_rng(0)
        rows = rng.integers(0, 256, (96, 128)).astype(np.float64)
        cols = rng.integers(0, 256, (160, 128)).astype(np.float64)
        rows[:32], cols[:32], cols[32:64] = 255.0, 255.0, 0.0  # shifted 127, -128
        exact = ((rows ** 2).sum(axis=1)[:, None] + (cols ** 2).sum(axis=1)
                 - 2.0 * rows @ cols.T)
        packed = np.c_[cols, np.ones((len(cols), 3)), norm_parts((cols ** 2).sum(axis=1))]
        product = int8_product(packed.astype(np.float32))
        block = np.c_[-2.0 * rows, norm_parts((rows ** 2).sum(axis=1)),
                      np.ones((len(rows), 3))].astype(np.float32)
        tile = np.empty(exact.shape, np.int32)
        product.fill(block, 0, len(cols), tile)
        got = (product.row_terms(block).astype(np.int64)[:, None] + product.col_terms
               + product.scale * tile.astype(np.int64))
        return bool(np.array_equal(got, exact))
    except (ImportError, AttributeError, RuntimeError, NotImplementedError):
        return False


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
