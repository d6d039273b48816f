"""The compiled kernels (core.compiled) of core.method.prior_adjustment, private to it: the
projection with its Jacobians, the per-observation products that make the normal equations, the
reduced camera system (the Schur complement over the points, camera pair by camera pair) and the
points' back-substitution."""
from __future__ import annotations

import numpy as np

from ..compiled import compiled


@compiled()
def _project(R, t, X, K, block_of, c_idx, p_idx, xy, res, A, B, fisheye):
    """Every observation's residual (projection - xy, px) into res (N, 2), and where A and B
    have rows (N, 2, 14) and (N, 2, 3) (zeros in A on entry) its Jacobians with respect to
    the camera's rotation (a left increment), translation and intrinsics (f, cx, cy, k1, k2,
    aspect, p1, p2: fy = f (1 + aspect)) and to the point. A block with fisheye[b] projects as
    OPENCV_FISHEYE instead (_project_fisheye: k3, k4 in p1's and p2's places). A point behind a
    perspective camera gets a large, constant residual."""
    jacobians = A.shape[0] > 0
    for n in range(c_idx.shape[0]):
        c, p = c_idx[n], p_idx[n]
        x = R[c, 0, 0] * X[p, 0] + R[c, 0, 1] * X[p, 1] + R[c, 0, 2] * X[p, 2] + t[c, 0]
        y = R[c, 1, 0] * X[p, 0] + R[c, 1, 1] * X[p, 1] + R[c, 1, 2] * X[p, 2] + t[c, 1]
        z = R[c, 2, 0] * X[p, 0] + R[c, 2, 1] * X[p, 1] + R[c, 2, 2] * X[p, 2] + t[c, 2]
        if fisheye[block_of[c]]:
            _project_fisheye(n, c, x, y, z, R, K[block_of[c]], xy, res, A, B, jacobians)
            continue
        z_safe = z if abs(z) > 1e-12 else 1e-12
        u, v = x / z_safe, y / z_safe
        b = block_of[c]
        f, cx, cy, k1, k2 = K[b, 0], K[b, 1], K[b, 2], K[b, 3], K[b, 4]
        a, p1, p2 = K[b, 5], K[b, 6], K[b, 7]
        r2 = u * u + v * v
        d = 1 + k1 * r2 + k2 * r2 * r2
        fy = f * (1 + a)
        uv = u * v
        xd = d * u + 2 * p1 * uv + p2 * (r2 + 2 * u * u)
        yd = d * v + p1 * (r2 + 2 * v * v) + 2 * p2 * uv
        if z <= 0:
            res[n, 0], res[n, 1] = 1e3, 1e3
        else:
            res[n, 0], res[n, 1] = f * xd + cx - xy[n, 0], fy * yd + cy - xy[n, 1]
        if not jacobians:
            continue
        dd_dr2 = k1 + 2 * k2 * r2
        # d(proj)/d(u, v), then d(proj)/d(camera point) through u = x / z, v = y / z
        j00 = f * (d + 2 * u * u * dd_dr2 + 2 * p1 * v + 6 * p2 * u)
        j01 = f * (2 * uv * dd_dr2 + 2 * p1 * u + 2 * p2 * v)
        j10 = fy * (2 * uv * dd_dr2 + 2 * p1 * u + 2 * p2 * v)
        j11 = fy * (d + 2 * v * v * dd_dr2 + 6 * p1 * v + 2 * p2 * u)
        for k, (ju, jv) in enumerate(((j00, j01), (j10, j11))):
            _point_and_pose_rows(n, k, c, ju / z_safe, jv / z_safe, -(ju * u + jv * v) / z_safe,
                                 x, y, z, R, A, B)
        A[n, 0, 6], A[n, 1, 6] = xd, (1 + a) * yd
        A[n, 0, 7], A[n, 1, 8] = 1.0, 1.0
        A[n, 0, 9], A[n, 1, 9] = f * u * r2, fy * v * r2
        A[n, 0, 10], A[n, 1, 10] = f * u * r2 * r2, fy * v * r2 * r2
        A[n, 1, 11] = f * yd
        A[n, 0, 12], A[n, 1, 12] = f * 2 * uv, fy * (r2 + 2 * v * v)
        A[n, 0, 13], A[n, 1, 13] = f * (r2 + 2 * u * u), fy * 2 * uv


@compiled()
def _point_and_pose_rows(n, k, c, d0, d1, d2, x, y, z, R, A, B):
    """Row k of observation n's Jacobians from d(proj_k)/d(camera point) = (d0, d1, d2), the
    point (x, y, z) in camera c's frame: B's (the world point, through R[c]) and A's rotation (a
    left increment) and translation columns."""
    for m in range(3):
        B[n, k, m] = d0 * R[c, 0, m] + d1 * R[c, 1, m] + d2 * R[c, 2, m]
    A[n, k, 0] = d2 * y - d1 * z  # rotation: -d(proj)/d(camera point) [camera point]x
    A[n, k, 1] = d0 * z - d2 * x
    A[n, k, 2] = d1 * x - d0 * y
    A[n, k, 3], A[n, k, 4], A[n, k, 5] = d0, d1, d2


@compiled()
def _project_fisheye(n, c, x, y, z, R, k, xy, res, A, B, jacobians):
    """_project's observation n of camera c (its point (x, y, z) in the camera's frame) through
    an OPENCV_FISHEYE lens, k = (f, cx, cy, k1, k2, aspect, k3, k4): the ray's angle from the
    axis theta = atan2(rho, z), rho = |(x, y)|, mapped to the radius theta (1 + k1 theta^2 +
    k2 theta^4 + k3 theta^6 + k4 theta^8) along (x, y) / rho. As COLMAP's model in front of the
    camera (theta = atan(rho / z) there); written with atan2, it holds beyond 90 deg from the
    axis, where a lens wider than 180 deg still images points."""
    f, cx, cy, k1, k2, a, k3, k4 = k[0], k[1], k[2], k[3], k[4], k[5], k[6], k[7]
    fy = f * (1 + a)
    rho2 = x * x + y * y
    rho = np.sqrt(rho2)
    n2 = rho2 + z * z
    if rho < 1e-9 * np.sqrt(n2) and z > 0:
        # on the axis: theta_d / rho -> 1 / z (the distortion's terms vanish with theta^2)
        xd, yd = x / z, y / z
        res[n, 0], res[n, 1] = f * xd + cx - xy[n, 0], fy * yd + cy - xy[n, 1]
        if not jacobians:
            return
        g = 1.0 / z
        rows = ((f * g, 0.0, -f * xd * g), (0.0, fy * g, -fy * yd * g))
        theta = 0.0
        ex, ey = 0.0, 0.0
    else:
        theta = np.arctan2(rho, z)
        t2 = theta * theta
        d = 1 + t2 * (k1 + t2 * (k2 + t2 * (k3 + t2 * k4)))
        theta_d = theta * d
        ex, ey = x / rho, y / rho  # the image direction of the ray
        xd, yd = ex * theta_d, ey * theta_d
        res[n, 0], res[n, 1] = f * xd + cx - xy[n, 0], fy * yd + cy - xy[n, 1]
        if not jacobians:
            return
        dtd = 1 + t2 * (3 * k1 + t2 * (5 * k2 + t2 * (7 * k3 + t2 * 9 * k4)))  # d theta_d / d theta
        # d theta / d(x, y, z) and d(ex, ey) / d(x, y, z)
        ht = dtd * z / (rho * n2)
        q = theta_d / (rho2 * rho)
        dxd = (y * y * q + ex * x * ht, -x * y * q + ex * y * ht, -ex * dtd * rho / n2)
        dyd = (-x * y * q + ey * x * ht, x * x * q + ey * y * ht, -ey * dtd * rho / n2)
        rows = ((f * dxd[0], f * dxd[1], f * dxd[2]), (fy * dyd[0], fy * dyd[1], fy * dyd[2]))
    for kk in range(2):
        _point_and_pose_rows(n, kk, c, rows[kk][0], rows[kk][1], rows[kk][2], x, y, z, R, A, B)
    A[n, 0, 6], A[n, 1, 6] = xd, (1 + a) * yd
    A[n, 0, 7], A[n, 1, 8] = 1.0, 1.0
    A[n, 1, 11] = f * yd
    t3 = theta * theta * theta
    for col, power in ((9, t3), (10, t3 * theta * theta), (12, t3 * theta ** 4),
                       (13, t3 * theta ** 6)):
        A[n, 0, col], A[n, 1, col] = f * ex * power, fy * ey * power


@compiled()
def _observation_products(res, A, B, w, used, c_idx, p_idx, num_cameras, num_points):
    """The weighted products of every observation's Jacobians (A (N, 2, 14) camera side, of
    which the columns `used` (K,); B (N, 2, 3) point side; w (N,) weights; res (N, 2)), summed
    per camera (A^T w A (C, K, K), A^T w r (C, K)) and per point (B^T w B (P, 3, 3), B^T w r
    (P, 3)), and per observation (A^T w B)^T (N, 3, K): one pass, each observation's rows in
    registers."""
    N, width = A.shape[0], used.shape[0]
    a_rows = np.empty((2, width))
    U_cam = np.zeros((num_cameras, width, width))
    g_cam = np.zeros((num_cameras, width))
    V = np.zeros((num_points, 3, 3))
    g_pt = np.zeros((num_points, 3))
    Wt = np.empty((N, 3, width))
    for n in range(N):
        c, p, wn = c_idx[n], p_idx[n], w[n]
        r0, r1 = res[n, 0], res[n, 1]
        b00, b01, b02 = B[n, 0, 0], B[n, 0, 1], B[n, 0, 2]
        b10, b11, b12 = B[n, 1, 0], B[n, 1, 1], B[n, 1, 2]
        for i in range(width):
            a_rows[0, i], a_rows[1, i] = A[n, 0, used[i]], A[n, 1, used[i]]
        for i in range(width):
            a0, a1 = a_rows[0, i] * wn, a_rows[1, i] * wn
            g_cam[c, i] += a0 * r0 + a1 * r1
            row = U_cam[c, i]
            for j in range(width):
                row[j] += a0 * a_rows[0, j] + a1 * a_rows[1, j]
            Wt[n, 0, i] = a0 * b00 + a1 * b10
            Wt[n, 1, i] = a0 * b01 + a1 * b11
            Wt[n, 2, i] = a0 * b02 + a1 * b12
        for k in range(3):
            e0, e1 = B[n, 0, k] * wn, B[n, 1, k] * wn
            g_pt[p, k] += e0 * r0 + e1 * r1
            V[p, k, 0] += e0 * b00 + e1 * b10
            V[p, k, 1] += e0 * b01 + e1 * b11
            V[p, k, 2] += e0 * b02 + e1 * b12
    return U_cam, g_cam, V, g_pt, Wt


@compiled()
def _point_products(Wt, V_inv, g_pt, first_obs, c_idx, num_cameras):
    """For every pair of cameras (a, b) the sum over the points both see of W_a V^-1 W_b^T
    (C, C, K, K), and per observation W V^-1 g_pt (N, K): Wt (N, 3, K) per observation,
    V_inv (P, 3, 3) and g_pt (P, 3) per point; first_obs (P + 1,): each point's first
    observation, its observations being contiguous and in camera order; c_idx (N,): each
    observation's camera. Each observation's W V^-1 is formed once, in a small array the
    pairs then read; V^-1 is symmetric, so the (b, a) block is the (a, b) block transposed:
    only a <= b is summed, the rest mirrored."""
    width = Wt.shape[2]
    out = np.zeros((num_cameras, num_cameras, width, width))
    yg = np.empty((Wt.shape[0], width))
    Y = np.empty((width, 3))
    for p in range(first_obs.shape[0] - 1):
        g0, g1, g2 = g_pt[p, 0], g_pt[p, 1], g_pt[p, 2]
        for a in range(first_obs[p], first_obs[p + 1]):
            for i in range(width):
                w0, w1, w2 = Wt[a, 0, i], Wt[a, 1, i], Wt[a, 2, i]
                for k in range(3):
                    Y[i, k] = w0 * V_inv[p, 0, k] + w1 * V_inv[p, 1, k] + w2 * V_inv[p, 2, k]
                yg[a, i] = Y[i, 0] * g0 + Y[i, 1] * g1 + Y[i, 2] * g2
            for b in range(a, first_obs[p + 1]):
                block = out[c_idx[a], c_idx[b]]
                w0, w1, w2 = Wt[b, 0], Wt[b, 1], Wt[b, 2]
                for i in range(width):
                    y0, y1, y2 = Y[i, 0], Y[i, 1], Y[i, 2]
                    row = block[i]
                    for j in range(width):
                        row[j] += y0 * w0[j] + y1 * w1[j] + y2 * w2[j]
    for a in range(num_cameras):
        for b in range(a + 1, num_cameras):
            out[b, a] = out[a, b].T
    return out, yg


@compiled()
def _to_columns(products, yg, camera_cols, obs_cols, size):
    """The camera pairs' blocks (C, C, K, K) and the observations' rows (N, K) summed into
    the columns of the cameras' parameters (camera_cols (C, K), obs_cols (N, K); a held one's
    is size - 1): (size, size) and (size,)."""
    S = np.zeros((size, size))
    r = np.zeros(size)
    C, width = camera_cols.shape
    for a in range(C):
        for b in range(C):
            for i in range(width):
                row = S[camera_cols[a, i]]
                for j in range(width):
                    row[camera_cols[b, j]] += products[a, b, i, j]
    for n in range(obs_cols.shape[0]):
        for i in range(width):
            r[obs_cols[n, i]] += yg[n, i]
    return S, r


@compiled()
def damped_point_inverses(V, lam):
    """Each point's 3x3 block with its diagonal scaled by 1 + lam (Levenberg-Marquardt's
    damping) and a ridge of 1e-9 of its trace (at least 1e-18) on the diagonal, inverted: a
    point whose observations do not fix it (all behind a camera, rays parallel) then moves by
    nothing instead of breaking the solve. The blocks are symmetric: the adjugate over the
    determinant."""
    out = np.empty_like(V)
    for p in range(V.shape[0]):
        a, b, c = V[p, 0, 0] * (1 + lam), V[p, 1, 1] * (1 + lam), V[p, 2, 2] * (1 + lam)
        ridge = 1e-9 * max(a + b + c, 1e-9)
        a, b, c = a + ridge, b + ridge, c + ridge
        d, e, f = V[p, 0, 1], V[p, 0, 2], V[p, 1, 2]
        c00, c01, c02 = b * c - f * f, e * f - d * c, d * f - e * b
        c11, c12, c22 = a * c - e * e, d * e - a * f, a * b - d * d
        inv_det = 1.0 / (a * c00 + d * c01 + e * c02)
        out[p, 0, 0], out[p, 0, 1], out[p, 0, 2] = c00 * inv_det, c01 * inv_det, c02 * inv_det
        out[p, 1, 0], out[p, 1, 1], out[p, 1, 2] = c01 * inv_det, c11 * inv_det, c12 * inv_det
        out[p, 2, 0], out[p, 2, 1], out[p, 2, 2] = c02 * inv_det, c12 * inv_det, c22 * inv_det
    return out


@compiled()
def point_steps(Wt, V_inv, g_pt, delta_cols, obs_cols, first_obs):
    """The points' step given the cameras' (back-substitution): per point
    V^-1 (-g_pt - sum over its observations of W^T delta), delta_cols (M + 1,) the cameras'
    step by column with a zero for the held ones' column M."""
    out = np.empty_like(g_pt)
    width = Wt.shape[2]
    for p in range(first_obs.shape[0] - 1):
        r0, r1, r2 = -g_pt[p, 0], -g_pt[p, 1], -g_pt[p, 2]
        for n in range(first_obs[p], first_obs[p + 1]):
            for i in range(width):
                d = delta_cols[obs_cols[n, i]]
                r0 -= Wt[n, 0, i] * d
                r1 -= Wt[n, 1, i] * d
                r2 -= Wt[n, 2, i] * d
        for k in range(3):
            out[p, k] = V_inv[p, k, 0] * r0 + V_inv[p, k, 1] * r1 + V_inv[p, k, 2] * r2
    return out
