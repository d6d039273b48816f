"""The compiled inner loop of the dense correspondences (core.method.dense_matches): affine
Lucas-Kanade with gain and offset, one patch at a time, sampling the images bicubically.

Why compiled: written as numpy passes over all patches at once, each of a patch's twelve
iterations made ~20 passes over (patches x 225 pixels x 8) arrays and one remap, and the
alignment cost ~0.4 ms a patch whatever the batch size (memory-bound); one patch at a time in
compiled code the same arithmetic stays in cache (docs/design-notes.md, Dense correspondences).

The samples are cv2.remap's (INTER_CUBIC, BORDER_REPLICATE) to float32 rounding: the
correspondences stay what they were when remap sampled them. Bicubic, not bilinear: bilinear
interpolation pulls sub-pixel alignments towards whole pixels (pixel locking), a bias that varies
smoothly over the image as a wrong lens would.
The functions release the GIL: dense_matches runs image pairs on threads."""
from __future__ import annotations

import numpy as np

from ..compiled import compiled

CUBIC_A = -0.75  # OpenCV's bicubic kernel (Keys' cubic convolution with a = -0.75)


@compiled(inline="always")
def _cubic_weights(x):
    """The cubic kernel's float32 weights of the four samples around a position x (0 <= x < 1)
    past the second."""
    a = np.float32(CUBIC_A)
    x1, x2 = np.float32(x + np.float32(1.0)), np.float32(np.float32(1.0) - x)
    w0 = ((a * x1 - 5 * a) * x1 + 8 * a) * x1 - 4 * a
    w1 = ((a + 2) * x - (a + 3)) * x * x + 1
    w2 = ((a + 2) * x2 - (a + 3)) * x2 * x2 + 1
    return w0, w1, w2, 1 - w0 - w1 - w2


@compiled(inline="always")
def _taps(x, size):
    """The four clamped (BORDER_REPLICATE) sample indices around position x along an axis of
    `size` samples, and their float32 cubic weights. Positions more than a pixel beyond the
    image (diverged patches, NaN) are brought to it first: all four taps are the edge sample
    there either way, and the index stays defined."""
    if not x >= -2.0:
        x = np.float32(-2.0)
    elif x > size + 1.0:
        x = np.float32(size + 1.0)
    fx = np.floor(x)
    w0, w1, w2, w3 = _cubic_weights(np.float32(x - fx))
    i = np.int64(fx) - 1
    if 0 <= i and i + 3 < size:
        return i, i + 1, i + 2, i + 3, w0, w1, w2, w3
    return (min(max(i, 0), size - 1), min(max(i + 1, 0), size - 1),
            min(max(i + 2, 0), size - 1), min(max(i + 3, 0), size - 1), w0, w1, w2, w3)


@compiled(inline="always")
def _sample(image, x, y, k):
    """The bicubic sample of channel k of image (H, W, channels) float32 at the OpenCV pixel
    position (x, y) (cv2.remap's INTER_CUBIC with BORDER_REPLICATE to float32 rounding: float32
    weights, each row summed, the rows weighted and added in order)."""
    c0, c1, c2, c3, wx0, wx1, wx2, wx3 = _taps(x, image.shape[1])
    r0, r1, r2, r3, wy0, wy1, wy2, wy3 = _taps(y, image.shape[0])
    total = wy0 * (image[r0, c0, k] * wx0 + image[r0, c1, k] * wx1
                   + image[r0, c2, k] * wx2 + image[r0, c3, k] * wx3)
    total += wy1 * (image[r1, c0, k] * wx0 + image[r1, c1, k] * wx1
                    + image[r1, c2, k] * wx2 + image[r1, c3, k] * wx3)
    total += wy2 * (image[r2, c0, k] * wx0 + image[r2, c1, k] * wx1
                    + image[r2, c2, k] * wx2 + image[r2, c3, k] * wx3)
    total += wy3 * (image[r3, c0, k] * wx0 + image[r3, c1, k] * wx1
                    + image[r3, c2, k] * wx2 + image[r3, c3, k] * wx3)
    return total


@compiled(inline="always")
def _row3(image, row, c0, c1, c2, c3, wx0, wx1, wx2, wx3, wy):
    """One row of _sample3: the three channels' weighted sums along the row, times wy."""
    a0, a1, a2, a3 = image[row, c0], image[row, c1], image[row, c2], image[row, c3]
    return (wy * (a0[0] * wx0 + a1[0] * wx1 + a2[0] * wx2 + a3[0] * wx3),
            wy * (a0[1] * wx0 + a1[1] * wx1 + a2[1] * wx2 + a3[1] * wx3),
            wy * (a0[2] * wx0 + a1[2] * wx1 + a2[2] * wx2 + a3[2] * wx3))


@compiled(inline="always")
def _sample3(image, x, y):
    """_sample of the three channels of image (H, W, 3), the taps found once."""
    c0, c1, c2, c3, wx0, wx1, wx2, wx3 = _taps(x, image.shape[1])
    r0, r1, r2, r3, wy0, wy1, wy2, wy3 = _taps(y, image.shape[0])
    v0, v1, v2 = _row3(image, r0, c0, c1, c2, c3, wx0, wx1, wx2, wx3, wy0)
    u0, u1, u2 = _row3(image, r1, c0, c1, c2, c3, wx0, wx1, wx2, wx3, wy1)
    v0, v1, v2 = v0 + u0, v1 + u1, v2 + u2
    u0, u1, u2 = _row3(image, r2, c0, c1, c2, c3, wx0, wx1, wx2, wx3, wy2)
    v0, v1, v2 = v0 + u0, v1 + u1, v2 + u2
    u0, u1, u2 = _row3(image, r3, c0, c1, c2, c3, wx0, wx1, wx2, wx3, wy3)
    return v0 + u0, v1 + u1, v2 + u2


@compiled()
def sample_bicubic(image, xy):
    """(N, channels) float32 bicubic samples (_sample) of image (H, W, channels) float32 at the
    OpenCV pixel positions xy (N, 2) float32."""
    out = np.empty((xy.shape[0], image.shape[2]), np.float32)
    for n in range(xy.shape[0]):
        for k in range(image.shape[2]):
            out[n, k] = _sample(image, xy[n, 0], xy[n, 1], k)
    return out


@compiled()
def _solve_in_place(H, g):
    """g <- H^-1 g for a small dense H (Gaussian elimination with partial pivoting; H is
    overwritten). False where H is singular."""
    n = H.shape[0]
    for col in range(n):
        pivot = col
        for r in range(col + 1, n):
            if abs(H[r, col]) > abs(H[pivot, col]):
                pivot = r
        if H[pivot, col] == 0.0:
            return False
        if pivot != col:
            for c in range(n):
                H[col, c], H[pivot, c] = H[pivot, c], H[col, c]
            g[col], g[pivot] = g[pivot], g[col]
        for r in range(col + 1, n):
            factor = H[r, col] / H[col, col]
            for c in range(col, n):
                H[r, c] -= factor * H[col, c]
            g[r] -= factor * g[col]
    for r in range(n - 1, -1, -1):
        acc = g[r]
        for c in range(r + 1, n):
            acc -= H[r, c] * g[c]
        g[r] = acc / H[r, r]
    return True


@compiled(inline="always")
def _position(off, maps, t_b, k, p):
    """float32 (x, y) of patch k's pixel p: t + map @ offset (float64, then rounded)."""
    ox, oy = np.float64(off[p, 0]), np.float64(off[p, 1])
    return (np.float32(ox * maps[k, 0, 0] + oy * maps[k, 0, 1] + t_b[k, 0]),
            np.float32(ox * maps[k, 1, 0] + oy * maps[k, 1, 1] + t_b[k, 1]))


@compiled()
def align(image_a, image_b3, xy_a, t_b, maps, off, iterations, converged_step_px, half_px):
    """Affine Lucas-Kanade of each patch of image_a (H, W, 1) float32 around xy_a (N, 2) float32
    onto image b, given as with_gradients (H, W, 3: image, x and y gradients), from t_b (N, 2)
    float64 and the maps (N, 2, 2) float64, both updated in place; off (P, 2) float32: the
    patch's pixel offsets. Per patch: Gauss-Newton on translation, the 2x2 map, gain and offset
    (float32 residuals and Jacobian, float64 normal equations with a 1e-6 ridge) until a step
    moves the patch by less than converged_step_px at its rim (half_px from the centre), at
    most `iterations` times. Returns the normalised cross-correlation (N,) of each patch with
    image b at the final position (0 where undefined)."""
    n_patches, n_px = xy_a.shape[0], off.shape[0]
    ncc = np.zeros(n_patches)
    template = np.empty(n_px, np.float32)
    J = np.empty((n_px, 8))
    r = np.empty(n_px)
    g = np.empty(8)
    for k in range(n_patches):
        for p in range(n_px):
            template[p] = _sample(image_a, np.float32(xy_a[k, 0] + off[p, 0]),
                                  np.float32(xy_a[k, 1] + off[p, 1]), 0)
        gain, bias = 1.0, 0.0
        for _ in range(iterations):
            g32, b32 = np.float32(gain), np.float32(bias)
            for p in range(n_px):
                x, y = _position(off, maps, t_b, k, p)
                ib, gx, gy = _sample3(image_b3, x, y)
                gx, gy = g32 * gx, g32 * gy
                r[p] = np.float32(g32 * ib + b32) - template[p]
                J[p, 0], J[p, 1] = gx, gy
                J[p, 2], J[p, 3] = gx * off[p, 0], gx * off[p, 1]
                J[p, 4], J[p, 5] = gy * off[p, 0], gy * off[p, 1]
                J[p, 6], J[p, 7] = ib, 1.0
            H = np.dot(J.T, J)
            g[:] = -np.dot(J.T, r)
            for i in range(8):
                H[i, i] += 1e-6
            if not _solve_in_place(H, g):
                break
            t_b[k, 0] += g[0]
            t_b[k, 1] += g[1]
            maps[k, 0, 0] += g[2]
            maps[k, 0, 1] += g[3]
            maps[k, 1, 0] += g[4]
            maps[k, 1, 1] += g[5]
            gain += g[6]
            bias += g[7]
            moved = max(abs(g[0]), abs(g[1])) + half_px * (abs(g[2]) + abs(g[3]) + abs(g[4])
                                                             + abs(g[5]))
            if not moved >= converged_step_px:  # NaN steps stop too
                break
        sum_a = sum_b = 0.0
        for p in range(n_px):
            x, y = _position(off, maps, t_b, k, p)
            r[p] = _sample(image_b3, x, y, 0)
            sum_a += template[p]
            sum_b += r[p]
        mean_a, mean_b = sum_a / n_px, sum_b / n_px
        ab = aa = bb = 0.0
        for p in range(n_px):
            da, db = template[p] - mean_a, r[p] - mean_b
            ab += da * db
            aa += da * da
            bb += db * db
        value = ab / np.sqrt(aa * bb + 1e-9)
        ncc[k] = value if np.isfinite(value) else 0.0
    return ncc
