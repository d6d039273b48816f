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

Where oneDNN has an 8-bit integer kernel that sums exactly (AMX or VNNI: int8_exact_here checks
it), the products are int8_product's instead: unsigned 8-bit row descriptors times the column
descriptors less 128 (signed 8-bit), summed in int32 and written as float32 with each column's
squared norm added by the same call, into a tile holding each row's own terms (its squared norm,
and 256 times its sum, which the shift by 128 takes out). The products, the fill included, take
under half the float path's time on a CPU with AMX (a quarter of the bytes in, no conversion of the
inputs; asift's matching 7-13 % less, its reductions and features being the rest), and the sums are
exact in int32, so again the distances are those of numpy's product to the bit.
"""
from __future__ import annotations

import contextlib
import functools
from typing import Callable, Iterator, Optional

import numpy as np

# Squared norms below this are integers whose three base-256 digits bfloat16 holds exactly, and
# whose sums with a product's terms stay below float32's 2^24 exact integers.
EXACT_BELOW = 2 ** 22
# int8_product's float32 partial sums stay below 2^24 (exact integers) where every squared norm
# is below this and descriptors have 128 values: |r.(c - 128)| <= |r| (|c| + 128 sqrt(128)),
# 2.5e6 for norms under 1024; twice that, plus |c|^2 and |r|^2 + 256 sum(r) (under 1.05e6 and
# 4e6), is 9.1e6. OpenCV's SIFT descriptors have norms of about 512.
INT8_NORMS_BELOW = 2 ** 20

Product = Callable[[np.ndarray, int, int, np.ndarray], None]


def integer_descriptors(desc: np.ndarray) -> bool:
    """Whether every value is an integer in 0-255 (OpenCV's SIFT; RootSIFT's are not)."""
    return bool(desc.size == 0 or (desc.min() >= 0 and desc.max() <= 255
                                   and np.array_equal(desc, np.round(desc))))


def int8_exact(desc: np.ndarray) -> bool:
    """Whether int8_product gives these descriptors' distances exactly (INT8_NORMS_BELOW);
    integer_descriptors must hold as well."""
    return bool(desc.size == 0 or (desc.shape[1] == 128 and np.einsum(
        "ij,ij->i", desc, desc, dtype=np.float64).max() < INT8_NORMS_BELOW))


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


def int8_product(cols: np.ndarray) -> Product:
    """The same product by oneDNN's 8-bit integer matmul (module docstring): only where
    int8_exact_here() and for columns of descriptors that integer_descriptors and int8_exact
    pass, under onednn_products. Each rows array is converted once (the tiles of a block row
    come one after another), each tile of columns packed once."""
    import torch

    desc_cols = cols[:, :-6]
    shifted = torch.from_numpy((desc_cols - 128.0).astype(np.int8))
    sq_norms = cols[:, -3:].sum(axis=1, dtype=np.float32)  # norm_parts: integers, exact
    packed: dict = {}
    converted: list = [None, None, None]  # rows, as unsigned 8-bit, each row's own terms

    def product(rows: np.ndarray, c0: int, c1: int, out: np.ndarray) -> None:
        if converted[0] is not rows:
            desc_rows = rows[:, :-6] * -0.5  # rows hold -2 x the descriptors (exact)
            converted[:] = [rows, torch.from_numpy(desc_rows.astype(np.uint8)),
                            rows[:, -6:-3].sum(axis=1) - 256.0 * desc_rows.sum(axis=1)]
        if (c0, c1) not in packed:
            packed[(c0, c1)] = (torch.ops.onednn.qlinear_prepack(shifted[c0:c1], None),
                                torch.full((c1 - c0,), -2.0),
                                torch.zeros(c1 - c0, dtype=torch.int64),
                                torch.from_numpy(sq_norms[c0:c1]))
        into = out if out.flags.c_contiguous else np.empty(out.shape, np.float32)
        into[...] = converted[2][:, None]
        _int8_sum_into(converted[1], *packed[(c0, c1)], into)
        if into is not out:
            out[...] = into
    return product


def _int8_sum_into(rows_u8, packed_cols, col_scales, col_zero_points, col_terms,
                   into: np.ndarray) -> None:
    """into += col_scales x (rows_u8 @ columns.T) + col_terms, by oneDNN (float32 out)."""
    import torch

    target = torch.from_numpy(into)
    result = torch.ops.onednn.qlinear_pointwise.binary(
        rows_u8, 1.0, 0, packed_cols, col_scales, col_zero_points, target, col_terms, 1.0, 0,
        torch.float32, 1.0, 0, "sum", 1.0, "none", [], "")
    if result.data_ptr() != target.data_ptr():  # a build that does not sum in place
        into[...] = result.numpy()


def onednn_product_for(descriptors: list[np.ndarray]) -> Callable[[np.ndarray], Product]:
    """int8_product where int8_exact_here() and int8_exact holds for every image's descriptors
    (integer_descriptors must), else onednn_product."""
    if int8_exact_here() and all(int8_exact(d) for d in descriptors):
        return int8_product
    return onednn_product


def int8_kernel_here() -> bool:
    """Whether torch has oneDNN's quantized matmul and this CPU an 8-bit integer dot product
    (AMX or VNNI): without one, oneDNN adds pairs of 8-bit products in saturating 16-bit lanes
    (255 x 127 twice is past 32767)."""
    try:
        import torch
        return bool(hasattr(torch.ops.onednn, "qlinear_pointwise") and (
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
        rows[:32], cols[:32], cols[32:64] = 255.0, 255.0, 0.0  # shifted 127, -128; sums < 2^24
        exact = ((rows ** 2).sum(axis=1)[:, None] + (cols ** 2).sum(axis=1)
                 - 2.0 * rows @ cols.T)
        packed = np.c_[cols, np.ones((len(cols), 3)), norm_parts((cols ** 2).sum(axis=1))]
        out = np.empty(exact.shape, np.float32)
        int8_product(packed.astype(np.float32))(
            np.c_[-2.0 * rows, norm_parts((rows ** 2).sum(axis=1)),
                  np.ones((len(rows), 3))].astype(np.float32), 0, len(cols), out)
        return bool(np.array_equal(out, exact))
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
