"""core.method.prior_adjustment: the MAP bundle adjustment with priors on the principal point and
the pixel aspect, on exact projections of a point cloud (sfm_fixtures) with Gaussian noise."""
import numpy as np
import pytest
from sfm_fixtures import centred_state, gt_rig, gt_tracks

from densecalib_ros.core.method.prior_adjustment import (INTRINSIC_NAMES, Priors, AdjustmentProblem,
                                                         damped_point_inverses,
                                                         normal_equations, point_steps,
                                                         reduced_system, adjust_with_priors)
from densecalib_ros.core.method.prior_covariance import posterior_covariance
from densecalib_ros.core.method.reconstruction import SfMState, project, triangulate_tracks
from densecalib_ros.core.types import CameraIntrinsics


def _rig_with_offset_points(num_cameras=5, seed=3):
    """Ground truth OPENCV cameras (principal points 1.5 % off-centre, fy/fx - 1 = 0.3 %)."""
    cams, poses = gt_rig(num_cameras, seed=seed, pp_jitter_px=0.0)
    rng = np.random.default_rng(seed)
    true = []
    for cam in cams:
        f, cx, cy, k1, k2 = cam.params
        cx += rng.choice([-1, 1]) * 0.015 * cam.width
        cy += rng.choice([-1, 1]) * 0.015 * cam.height
        true.append(CameraIntrinsics("OPENCV", cam.width, cam.height,
                                     np.array([f, f * 1.003, cx, cy, k1, k2, 0.0, 0.0])))
    return true, poses


def _pp(cam):
    return np.asarray(cam.params)[[2, 3]] if cam.model in ("OPENCV", "OPENCV_FISHEYE") \
        else cam.params[[1, 2]]


def _fisheye_rig(num_cameras=5, seed=3):
    """Ground truth OPENCV_FISHEYE cameras (~150 deg across the diagonal: sfm_fixtures.gt_rig),
    their principal points 1.5 % of each side off-centre, fy / fx - 1 = 0.2 %, k3 and k4 not
    zero; and the SfMState the pipeline would hand the refinement: their tracks with 0.2 px of
    noise, the intrinsics' start at the image centre with the SfM's two-term distortion."""
    cams, poses = gt_rig(num_cameras, model="OPENCV_FISHEYE", seed=seed)
    rng = np.random.default_rng(seed)
    true = []
    for cam in cams:
        fx, _, cx, cy, k1, k2, _, _ = cam.params
        true.append(CameraIntrinsics("OPENCV_FISHEYE", cam.width, cam.height, np.array([
            fx, fx * 1.002, cx + rng.choice([-1, 1]) * 0.015 * cam.width,
            cy + rng.choice([-1, 1]) * 0.015 * cam.height, k1, k2, 0.004, -0.002])))
    tracks = gt_tracks(true, poses, num_points=3000, noise_px=0.2, outlier_frac=0.0, seed=0)
    state = SfMState.create(tracks, [CameraIntrinsics("OPENCV_FISHEYE", c.width, c.height, np.r_[
        c.params[0], c.params[0], c.width / 2, c.height / 2, c.params[4:6], 0.0, 0.0])
        for c in true])
    state.cam_from_world = [T.copy() for T in poses]
    triangulate_tracks(state, max_error_px=50.0)
    return true, state


@pytest.mark.parametrize("behind", [False, True])
def test_the_fisheye_projection_is_colmaps_and_holds_beyond_90_degrees(behind):
    """kernels._project_fisheye: OPENCV_FISHEYE as COLMAP projects it in front of the camera,
    the ray's angle from the axis continued past 90 deg (a lens wider than 180 deg), on the axis
    too; its Jacobians match finite differences there as well."""
    import pycolmap
    from densecalib_ros.core.method.prior_adjustment_kernels import _project

    rng = np.random.default_rng(1)
    X = rng.normal(size=(40, 3))
    X[:, 2] = -0.3 if behind else np.abs(X[:, 2]) + 0.05  # behind: 90-180 deg from the axis
    X[0] = [0.0, 0.0, 2.0]  # on the axis
    K = np.array([[400.0, 640.0, 360.0, 0.04, -0.015, 0.001, 0.004, -0.002]])
    one = np.zeros(len(X), np.int64)

    def project(points, k, jacobians=False):
        res, A, B = np.empty((len(X), 2)), np.zeros((len(X) if jacobians else 0, 2, 14)), \
            np.empty((len(X) if jacobians else 0, 2, 3))
        _project(np.eye(3)[None], np.zeros((1, 3)), points, k, np.zeros(1, np.int64), one,
                 np.arange(len(X)), np.zeros((len(X), 2)), res, A, B, np.array([True]))
        return res, A, B

    res, A, B = project(X, K, True)
    if not behind:
        cam = pycolmap.Camera.create_from_model_name(1, "OPENCV_FISHEYE", 400.0, 1280, 720)
        cam.params = [400.0, 400.4, 640.0, 360.0, 0.04, -0.015, 0.004, -0.002]
        assert np.abs(cam.img_from_cam(X) - res).max() < 1e-9
    else:  # beyond 90 deg: along the ray's direction, at the radius of its angle (> 90 deg)
        theta = np.arctan2(np.linalg.norm(X[1:, :2], axis=1), X[1:, 2])
        assert np.all(theta > np.pi / 2)
        t2 = theta ** 2
        radius = theta * (1 + t2 * (0.04 + t2 * (-0.015 + t2 * (0.004 - 0.002 * t2))))
        direction = X[1:, :2] / np.linalg.norm(X[1:, :2], axis=1)[:, None]
        assert np.allclose(res[1:], [640.0, 360.0] + [400.0, 400.4] * radius[:, None] * direction)
    eps = 1e-6
    for k, col in enumerate((6, 7, 8, 9, 10, 11, 12, 13)):  # f, cx, cy, k1, k2, aspect, k3, k4
        moved = K.copy()
        moved[0, k] += eps
        assert np.allclose((project(X, moved)[0] - res) / eps, A[:, :, col], rtol=1e-3,
                           atol=1e-3), col
    for m in range(3):
        moved = X.copy()
        moved[:, m] += eps
        assert np.allclose((project(moved, K)[0] - res) / eps, B[:, :, m], rtol=1e-3, atol=1e-3)


def test_fisheye_cameras_are_adjusted_with_their_principal_points_and_four_terms():
    """OPENCV_FISHEYE blocks: from the image centre and the SfM's two distortion terms, the
    adjustment recovers each camera's principal point and its projection as a whole (k3, k4
    free as k1, k2 are: over a 150 deg field the four terms trade off against each other and
    the focal length, the map they make over the images does not) from the images, and writes
    the cameras back as OPENCV_FISHEYE."""
    true, state = _fisheye_rig()
    blocks = list(range(len(true)))
    before = [np.linalg.norm(_pp(state.intrinsics[b]) - _pp(cam)) for b, cam in enumerate(true)]
    adjustment = adjust_with_priors(state, blocks, Priors({b: 6.4 for b in blocks},
                                                          {b: 0.003 for b in blocks}))
    assert adjustment.noise_px < 0.25  # the 0.2 px of the tracks: the model fits them
    for b, cam in enumerate(true):
        got = state.intrinsics[b]
        assert got.model == "OPENCV_FISHEYE"
        assert before[b] > 10.0 and np.linalg.norm(_pp(got) - _pp(cam)) < 2.0, b
        seen = state.tracks.xy_px[state.tracks.observed()[:, b], b]  # where the images speak
        rays = cam.to_pycolmap().cam_ray_from_img(seen)
        assert np.median(np.linalg.norm(got.to_pycolmap().img_from_cam(rays) - seen, axis=1)) \
            < 2.0, b


def test_jacobians_match_finite_differences():
    true, poses = _rig_with_offset_points(3)
    state = centred_state(true, poses, 0.0)
    state.intrinsics = [CameraIntrinsics("OPENCV", c.width, c.height,
                                         c.params + np.r_[0, 0, 0, 0, 0, 0, 1e-3, -2e-3])
                        for c in true]
    priors = Priors({b: 10.0 for b in range(3)}, {b: 0.01 for b in range(3)},
                    {b: 0.01 for b in range(3)})
    problem = AdjustmentProblem(state, [0, 1, 2], priors)
    res, A, B = problem.residuals_and_jacobians()
    obs = 7  # an observation of a camera whose pose is free
    obs = int(np.flatnonzero(problem.c_idx != problem.reference)[obs])
    c, b, p = problem.c_idx[obs], problem.block_of[problem.c_idx[obs]], problem.p_idx[obs]
    eps = 1e-6
    for k in range(len(INTRINSIC_NAMES)):
        problem.K[b, k] += eps
        moved = problem.residuals_and_jacobians(False)[obs]
        problem.K[b, k] -= eps
        assert np.allclose((moved - res[obs]) / eps, A[obs, :, 6 + k], rtol=1e-3, atol=1e-3), \
            INTRINSIC_NAMES[k]
    for k in range(3):
        problem.X[p, k] += eps
        moved = problem.residuals_and_jacobians(False)[obs]
        problem.X[p, k] -= eps
        assert np.allclose((moved - res[obs]) / eps, B[obs, :, k], rtol=1e-3, atol=1e-3)
    delta = np.zeros(problem.num_cam_params)
    for k in range(6):
        delta[:] = 0.0
        delta[problem.pose_cols[c, k]] = eps
        saved = problem.apply(delta, np.zeros_like(problem.X))
        moved = problem.residuals_and_jacobians(False)[obs]
        problem.restore(saved)
        assert np.allclose((moved - res[obs]) / eps, A[obs, :, k], rtol=1e-3, atol=1e-3)


@pytest.mark.parametrize("shared", [False, True])
def test_the_reduced_system_is_the_schur_complement_of_the_normal_equations(shared):
    """The reduced camera system (the compiled per-point products scattered into the cameras'
    columns) equals U - W V^-1 W^T formed densely, and its right-hand side -g_cam + W V^-1 g_pt,
    also where cameras share one intrinsics block (their columns coincide)."""
    true, poses = _rig_with_offset_points(4)
    state = centred_state(true, poses, 0.3)
    if shared:
        shared_state = SfMState.create(state.tracks, state.intrinsics, share_intrinsics=True)
        shared_state.cam_from_world, shared_state.points_xyz = state.cam_from_world, \
            state.points_xyz
        state = shared_state
    blocks = list(range(len(state.intrinsics)))
    priors = Priors({b: 10.0 for b in blocks}, aspect_std={b: 0.01 for b in blocks})
    problem = AdjustmentProblem(state, blocks, priors)
    U, Wt, V, g_cam, g_pt, flat, _ = normal_equations(problem, 0.5)
    V_inv = np.linalg.inv(V)
    S, rhs = reduced_system(problem, U, Wt, V_inv, g_cam, g_pt)
    M, P = problem.num_cam_params, len(problem.X)
    W = np.zeros((M + 1, P, 3))  # W_p per point; row M: the held parameters
    for n in range(len(problem.p_idx)):
        W[flat[n], problem.p_idx[n]] += Wt[n].T
    expected = U - np.einsum("mpi,pij,npj->mn", W, V_inv, W, optimize=True)[:M, :M]
    assert np.abs(S - expected).max() <= 1e-9 * np.abs(expected).max()
    expected_rhs = -g_cam + np.einsum("mpi,pij,pj->m", W, V_inv, g_pt, optimize=True)[:M]
    assert np.abs(rhs - expected_rhs).max() <= 1e-9 * np.abs(expected_rhs).max()


def test_a_step_solves_the_damped_normal_equations():
    """One Levenberg-Marquardt step through the compiled kernels (the points' damped and ridged
    inverses, the reduced system and its right-hand side, the points' back-substitution) equals
    the dense solve of the whole damped system, cameras and points together; one camera's
    principal point held and the tangential parameters held, so that held columns and the
    columns no camera frees are both dropped."""
    true, poses = _rig_with_offset_points(4)
    state = centred_state(true, poses, 0.3, num_points=150)
    blocks = list(range(4))
    priors = Priors({0: None, 1: 10.0, 2: 10.0, 3: 10.0}, aspect_std={b: 0.01 for b in blocks})
    problem = AdjustmentProblem(state, blocks, priors)
    assert len(problem.used) == 12  # p1, p2 held for every camera
    U, Wt, V, g_cam, g_pt, flat, _ = normal_equations(problem, 0.3)
    lam = 1e-2
    Ud = U + lam * np.diag(np.maximum(np.diag(U), 1e-9))
    V_inv = damped_point_inverses(V, lam)
    S, rhs = reduced_system(problem, Ud, Wt, V_inv, g_cam, g_pt)
    delta_cam = np.linalg.solve(S, rhs)
    delta_pts = point_steps(Wt, V_inv, g_pt, np.r_[delta_cam, 0.0], flat, problem.first_obs)

    M, P = problem.num_cam_params, len(problem.X)
    H = np.zeros((M + 1 + 3 * P, M + 1 + 3 * P))  # row and column M: the held parameters
    H[:M, :M] = Ud
    for n in range(len(problem.p_idx)):
        rows, p = flat[n], problem.p_idx[n]
        for k, row in enumerate(rows):
            H[row, M + 1 + 3 * p:M + 4 + 3 * p] += Wt[n, :, k]
    for p in range(P):
        Vd = V[p] + lam * np.diag(np.diag(V[p]))
        Vd += 1e-9 * np.trace(Vd) * np.eye(3)
        H[M + 1 + 3 * p:M + 4 + 3 * p, M + 1 + 3 * p:M + 4 + 3 * p] = Vd
    H[M + 1:, :M + 1] = H[:M + 1, M + 1:].T
    keep = np.r_[np.arange(M), np.arange(M + 1, len(H))]
    expected = np.linalg.solve(H[np.ix_(keep, keep)], -np.r_[g_cam, g_pt.ravel()])
    assert np.allclose(delta_cam, expected[:M], rtol=1e-7, atol=1e-9 * np.abs(expected[:M]).max())
    assert np.allclose(delta_pts.ravel(), expected[M:], rtol=1e-7,
                       atol=1e-9 * np.abs(expected[M:]).max())


@pytest.mark.parametrize("num_cameras, pp_std_px", [(3, 10.0), (3, 1e4), (5, 1e4)])
def test_the_covariance_is_that_of_the_gauge_held_also_in_weak_directions(num_cameras,
                                                                          pp_std_px):
    """The intrinsics' posterior covariance is the exact marginal whichever coordinate holds
    the gauge: the inverse of the reduced system with each point's block pseudo-inverted (so
    the scale is exactly free), held here on each non-reference camera in turn, on rigs whose
    system spans 12-13 orders of magnitude: three cameras with their principal points weakly
    held or free, five with them free. The points' blocks ridged as in the solve resisted the
    scale and moved a weak direction's sigma by up to 8 % with the choice (cy, three cameras);
    a pseudo-inverse of the raw system put these focal sigmas 4-74x too small."""
    true, poses = _rig_with_offset_points(num_cameras)
    state = centred_state(true, poses, 0.3)
    blocks = list(range(num_cameras))
    priors = Priors({b: pp_std_px for b in blocks}, aspect_std={b: 0.003 for b in blocks})
    adjust_with_priors(state, blocks, priors, noise_px=0.3)
    problem = AdjustmentProblem(state, blocks, priors)
    U, Wt, V, g_cam, g_pt, _, _ = normal_equations(problem, 0.3)
    S, _ = reduced_system(problem, U, Wt, np.linalg.pinv(V, hermitian=True), g_cam, g_pt)
    covariance = posterior_covariance(state, blocks, priors, 0.3)
    others = [c for c in state.registered() if c != problem.reference]
    for other in others:
        keep = np.ones(len(S), bool)
        keep[problem.pose_cols[other][3 + np.argmax(np.abs(problem.t[other]))]] = False
        held = S[np.ix_(keep, keep)]
        d = 1.0 / np.sqrt(np.diag(held))
        expected = np.zeros_like(S)
        expected[np.ix_(keep, keep)] = np.linalg.inv(held * d[:, None] * d[None, :]) * \
            d[:, None] * d[None, :]
        for b in blocks:
            free = np.flatnonzero(problem.intr_cols[b] >= 0)
            cols = problem.intr_cols[b][free]
            assert np.allclose(np.sqrt(np.diag(covariance[b])[free]),
                               np.sqrt(np.diag(expected)[cols]), rtol=1e-6), (other, b)


def test_a_point_at_a_cameras_centre_leaves_the_covariance_as_without_it():
    """A point a hair's breadth from a camera's centre (its 3x3 information conditioned
    ~3e12, as a fold's adjustment left 37 of a generated rig's points) is left out of the
    covariance, which then equals the covariance without its observations. Its share of the
    reduced system, a near-cancellation of ~1e24 against the cameras' own information, made
    the covariance NaN."""
    true, poses = _rig_with_offset_points(3)
    state = centred_state(true, poses, 0.3)
    blocks = list(range(3))
    priors = Priors({b: 10.0 for b in blocks}, aspect_std={b: 0.003 for b in blocks})
    adjust_with_priors(state, blocks, priors, noise_px=0.3)
    t = int(np.flatnonzero(state.active[:, 0] & state.active[:, 1]
                           & np.isfinite(state.points_xyz[:, 0]))[0])
    without = state.copy()
    without.active[t] = False
    expected = posterior_covariance(without, blocks, priors, 0.3)
    centre = -state.cam_from_world[1][:3, :3].T @ state.cam_from_world[1][:3, 3]
    state.points_xyz[t] = centre + 2e-9 * state.cam_from_world[1][2, :3]  # on camera 1's axis, in front
    for c in np.flatnonzero(state.active[t]):
        state.tracks.xy_px[t, c] = project(state, int(c), state.points_xyz[t][None])[0]
    covariance = posterior_covariance(state, blocks, priors, 0.3)
    for b in blocks:
        assert np.isfinite(covariance[b]).all()
        free = np.diag(expected[b]) > 0
        assert np.allclose(np.diag(covariance[b])[free], np.diag(expected[b])[free], rtol=1e-6)


def test_exact_tracks_give_the_exact_cameras_without_priors():
    true, poses = _rig_with_offset_points()
    state = centred_state(true, poses, 0.0)
    blocks = list(range(len(true)))
    adjust_with_priors(state, blocks, Priors({b: np.inf for b in blocks},
                                             {b: np.inf for b in blocks}), max_iterations=200)
    for b, cam in enumerate(true):
        assert state.intrinsics[b].model == "OPENCV"
        assert np.allclose(state.intrinsics[b].params, cam.params, rtol=1e-5, atol=1e-3)


def test_images_that_determine_the_principal_point_move_it_to_the_truth():
    true, poses = _rig_with_offset_points()
    state = centred_state(true, poses, 0.2)
    blocks = list(range(len(true)))
    result = adjust_with_priors(state, blocks, Priors({b: 6.4 for b in blocks},
                                                      {b: 0.003 for b in blocks}))
    covariance = posterior_covariance(state, blocks, result.priors, result.noise_px)
    for b, cam in enumerate(true):
        error = np.linalg.norm(_pp(state.intrinsics[b]) - _pp(cam))
        sigma = np.sqrt(max(covariance[b][1, 1], covariance[b][2, 2]))
        assert error < 3.0, (b, error)  # started 13.5 px off
        assert error < 4 * np.sqrt(2) * sigma, (b, error, sigma)
        # This layout barely sees the aspect: it stays within its (prior-led) sigma.
        aspect = state.intrinsics[b].params[1] / state.intrinsics[b].params[0] - 1
        assert abs(aspect - 0.003) < 3 * np.sqrt(covariance[b][5, 5])
    assert result.cost_after < result.cost_before
    assert 0.1 < result.noise_px < 0.3  # the 0.2 px noise, re-measured at the solution


def test_a_tight_prior_holds_the_principal_point_and_a_held_one_does_not_move():
    true, poses = _rig_with_offset_points()
    state = centred_state(true, poses, 0.2)
    blocks = list(range(len(true)))
    adjust_with_priors(state, blocks, Priors({b: 0.05 for b in blocks}, {}))
    for b in blocks:
        assert np.linalg.norm(_pp(state.intrinsics[b]) - [320.0, 240.0]) < 0.5
        assert state.intrinsics[b].model == "RADIAL"  # aspect held: no OPENCV needed
    held = centred_state(true, poses, 0.2)
    adjust_with_priors(held, blocks, Priors())
    for b in blocks:
        assert np.array_equal(_pp(held.intrinsics[b]), [320.0, 240.0])


def test_the_prior_centres_on_a_given_point():
    """A previous calibration's principal point as the prior's centre (a recalibration): a
    tight prior holds the point there, not at the image centre."""
    true, poses = _rig_with_offset_points()
    state = centred_state(true, poses, 0.2)
    blocks = list(range(len(true)))
    centres = {b: tuple(_pp(true[b]) + [3.0, -2.0]) for b in blocks}
    adjust_with_priors(state, blocks, Priors({b: 0.05 for b in blocks},
                                             principal_point_centre_px=centres))
    for b in blocks:
        assert np.linalg.norm(_pp(state.intrinsics[b]) - centres[b]) < 0.5, b


def test_fixed_blocks_are_left_alone():
    true, poses = _rig_with_offset_points(4)
    state = centred_state(true, poses, 0.2)
    before = state.intrinsics[2].params.copy()
    adjust_with_priors(state, [0, 1, 3], Priors({b: 6.4 for b in (0, 1, 3)}, {}))
    assert np.array_equal(state.intrinsics[2].params, before)
    with pytest.raises(ValueError, match="FULL_OPENCV"):
        other = centred_state(true, poses, 0.2)
        other.intrinsics[0] = CameraIntrinsics("FULL_OPENCV", 640, 480, np.r_[
            300.0, 300.0, 320, 240, np.zeros(8)])
        adjust_with_priors(other, [0], Priors())


def test_a_tie_pulls_the_cameras_together_and_leaves_their_level_free():
    """Priors.ties: a tight tie on the focal length gives every camera the same focal, at the
    level the images put the rig's (not at any given value); a loose one leaves each camera's
    own estimate."""
    true, poses = _rig_with_offset_points()
    blocks = list(range(len(true)))
    for b, cam in enumerate(true):  # one lens model: focal lengths 0.5-2 % apart
        cam.params[:2] = 600.0 * (1.0 + 0.005 * b) * np.array([1.0, 1.003])
    pp = {b: 6.4 for b in blocks}
    free = centred_state(true, poses, 0.2)
    adjust_with_priors(free, blocks, Priors(pp))
    tight = centred_state(true, poses, 0.2)
    adjust_with_priors(tight, blocks, Priors(pp, ties=[(0, {b: 1e-3 for b in blocks})]))
    loose = centred_state(true, poses, 0.2)
    adjust_with_priors(loose, blocks, Priors(pp, ties=[(0, {b: 1e3 for b in blocks})]))
    tied = np.array([tight.intrinsics[b].params[0] for b in blocks])
    assert np.ptp(tied) < 0.01
    own = np.array([free.intrinsics[b].params[0] for b in blocks])
    assert abs(tied.mean() / own.mean() - 1) < 0.003  # the level: the images' (spread 2 %)
    for b in blocks:
        assert abs(loose.intrinsics[b].params[0] - own[b]) < 0.05
