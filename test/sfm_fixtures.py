"""Ground-truth rigs and tracks for the SfM tests (test_global_sfm, test_incremental): exact
projections of a random point cloud plus noise and outliers, so the SfM stages are tested on their
own. World frame: the cloud fills x in [-3, 3], y in [-2, 2], z in [4.5, 9]. Also turned_image:
what a camera sees after a bump that turned it (the recalibration tests).
Imported as `sfm_fixtures` (pytest puts test/ on sys.path)."""
import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera, Tracks


def pose(euler_deg, t):
    """4x4 transform with the rotation of xyz Euler angles [deg] and the translation t."""
    m = np.eye(4)
    m[:3, :3] = Rotation.from_euler("xyz", euler_deg, degrees=True).as_matrix()
    m[:3, 3] = t
    return m


def look_at(centre, target):
    """4x4 cam_from_world of a camera at `centre` (3,) whose optical axis (+z) points at `target`
    (3,), with its x axis in the world xz plane and its y axis towards world -y."""
    z = (target - centre) / np.linalg.norm(target - centre)
    x = np.cross([0.0, -1.0, 0.0], z)
    x /= np.linalg.norm(x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, np.cross(z, x), z])
    T[:3, 3] = -T[:3, :3] @ centre
    return T


def gt_rig(num_cameras=5, model="RADIAL", width=640, height=480, seed=0, pp_jitter_px=3.0,
           k1_range=(-0.05, 0.02), k2_max=0.01, fisheye_draws_focal=False):
    """(cams, poses): num_cameras CameraIntrinsics and their 4x4 cam_from_world, on a 60 deg arc of
    radius 6 around (0, 0, 6), looking at that point (centres and targets jittered).
    RADIAL: focal width * U(0.8, 1.1), principal point the image centre +- pp_jitter_px,
    k1 ~ U(*k1_range), k2 ~ U(-k2_max, k2_max). OPENCV_FISHEYE: ~150 deg diagonal, k1 ~ U(+-0.05).
    fisheye_draws_focal: fisheye rigs still draw (and ignore) the RADIAL focal factor, which shifts
    the rest of their random stream (test_incremental's rigs are made so)."""
    rng = np.random.default_rng(seed)
    cams, poses = [], []
    for c in range(num_cameras):
        a = np.radians(-30 + 60 * c / max(num_cameras - 1, 1))
        centre = np.array([6 * np.sin(a), rng.uniform(-0.5, 0.5), 6 - 6 * np.cos(a)])
        poses.append(look_at(centre, np.array([0.0, 0.0, 6.0]) + rng.normal(0, 0.2, 3)))
        if model == "RADIAL" or fisheye_draws_focal:
            f = width * rng.uniform(0.8, 1.1)
        if model == "RADIAL":
            params = [f, width / 2 + rng.uniform(-pp_jitter_px, pp_jitter_px),
                      height / 2 + rng.uniform(-pp_jitter_px, pp_jitter_px),
                      rng.uniform(*k1_range), rng.uniform(-k2_max, k2_max)]
        else:  # OPENCV_FISHEYE, ~150 deg diagonal
            f = width / 3.2
            params = [f, f, width / 2, height / 2, rng.uniform(-0.05, 0.05), 0.01, 0.0, 0.0]
        cams.append(CameraIntrinsics(model, width, height, np.array(params)))
    return cams, poses


def gt_tracks(cams, poses, num_points=2500, noise_px=0.3, outlier_frac=0.03, seed=0,
              groups=None, random_scores=True, points_xyz=None):
    """Tracks (xy_px (T, C, 2) in COLMAP pixels, NaN where unobserved; T <= num_points) of random
    scene points, each seen by a random 2-4-camera subset of the cameras that see it (like sampled
    n-cycles), with N(0, noise_px) pixel noise; a fraction outlier_frac has one observation
    replaced by a uniform random pixel. cams / poses: as from gt_rig (poses are cam_from_world).
    groups: camera index lists; a track's cameras then all come from one group (a disconnected
    view graph). random_scores: scores ~ U(0.2, 1) (drawn last), else all 1.
    points_xyz: (N, 3) world points to use instead of the random cloud (num_points ignored)."""
    rng = np.random.default_rng(seed)
    C = len(cams)
    if points_xyz is None:
        X = rng.uniform([-3, -2, 4.5], [3, 2, 9], (num_points, 3))
    else:
        X = np.asarray(points_xyz, dtype=np.float64)
        num_points = len(X)
    xy = np.full((num_points, C, 2), np.nan)
    for c, (cam, T) in enumerate(zip(cams, poses)):
        X_cam = X @ T[:3, :3].T + T[:3, 3]
        p = cam.to_pycolmap().img_from_cam(X_cam)
        inside = (X_cam[:, 2] > 0) & np.all((p > 0) & (p < [cam.width, cam.height]), axis=1)
        xy[inside, c] = p[inside] + rng.normal(0, noise_px, (inside.sum(), 2))
    groups = groups or [list(range(C))]
    order = np.zeros(num_points, np.int32)
    for t in range(num_points):
        group = groups[t % len(groups)]
        seen = [c for c in group if not np.isnan(xy[t, c, 0])]
        if len(seen) < 2:
            continue
        keep = rng.choice(seen, rng.integers(2, min(4, len(seen)) + 1), replace=False)
        xy[t, np.setdiff1d(np.arange(C), keep)] = np.nan
        order[t] = len(keep)
        if rng.random() < outlier_frac:
            xy[t, keep[0]] = rng.uniform([0, 0], [cams[keep[0]].width, cams[keep[0]].height])
    valid = order > 0
    score = rng.uniform(0.2, 1.0, valid.sum()) if random_scores else np.ones(valid.sum())
    return Tracks(xy[valid], order[valid], score, np.zeros(valid.sum(), np.int32))


def gt_calibration(names, cams, poses):
    """The ground-truth RigCalibration: camera names[i] has cams[i] and cam_from_rig =
    poses[i] @ inv(poses[0]) (poses are 4x4 cam_from_world; names[0] is the reference)."""
    ref_inv = np.linalg.inv(poses[0])
    return RigCalibration(names[0], {n: RigCamera(n, cam, T @ ref_inv)
                                     for n, cam, T in zip(names, cams, poses)})


def refocused_image(image, intrinsics, focal_scale):
    """What a camera sees after its focal length was scaled (a refocus or zoom): the image scaled
    about the principal point, whatever the lens model (the focal scales the pixel offsets)."""
    camera = intrinsics.to_pycolmap()
    cx, cy = camera.principal_point_x, camera.principal_point_y
    h, w = image.shape[:2]
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)  # COLMAP pixel centres
    map_x = (cx + (xs - cx) / focal_scale - 0.5).astype(np.float32)
    map_y = (cy + (ys - cy) / focal_scale - 0.5).astype(np.float32)
    return cv2.remap(image, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def turned_image(image, intrinsics, cam_new_from_cam):
    """What a camera sees after turning about its optical centre (cam_new_from_cam: 3x3), lens
    distortion included: each new pixel's ray, back in the old camera, sampled there."""
    camera = intrinsics.to_pycolmap()
    h, w = image.shape[:2]
    xs, ys = np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5)  # COLMAP pixel centres
    rays_new = np.column_stack([camera.cam_from_img(np.column_stack([xs.ravel(), ys.ravel()])),
                                np.ones(xs.size)])
    source = camera.img_from_cam(rays_new @ cam_new_from_cam)  # rows: R^T ray (new -> old)
    maps = (source - 0.5).reshape(h, w, 2).astype(np.float32)
    return cv2.remap(image, maps[..., 0], maps[..., 1], cv2.INTER_LINEAR,
                     borderMode=cv2.BORDER_REPLICATE)


def centred_state(true, poses, noise_px, seed=0, num_points=3000):
    """An SfMState of tracks of the `true` cameras (OPENCV) at their `poses`, with the principal
    points at the image centre and square pixels (what the pipeline hands the image refinement),
    points triangulated."""
    from densecalib_ros.core.method.reconstruction import SfMState, triangulate_tracks

    tracks = gt_tracks(true, poses, num_points=num_points, noise_px=noise_px, outlier_frac=0.0,
                       seed=seed)
    start = [CameraIntrinsics("RADIAL", c.width, c.height,
                              np.array([c.params[0], c.width / 2, c.height / 2, c.params[4],
                                        c.params[5]])) for c in true]
    state = SfMState.create(tracks, start)
    state.cam_from_world = [T.copy() for T in poses]
    triangulate_tracks(state, max_error_px=50.0)
    return state
