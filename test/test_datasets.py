"""Loaders of real image sets: the reference cameras must be consistent with the images."""
import cv2
import numpy as np
import pytest

from densecalib_ros.eval.datasets import default_data_dir, load_strecha

STRECHA = default_data_dir() / "strecha_entry_p10"
needs_strecha = pytest.mark.skipif(
    not (STRECHA / "gt_dense_cameras").is_dir(),
    reason=f"Strecha entry-P10 not found at {STRECHA} (set DENSECALIB_DATA to the shared data dir)")


def _epipolar_distances_px(scene, a, b):
    """Distances of SIFT matches of images a, b to the epipolar lines of the reference cameras."""
    sift = cv2.SIFT_create(4000)
    ia, ib = (cv2.cvtColor(scene.frame_sets[0][k], cv2.COLOR_RGB2GRAY) for k in (a, b))
    ka, da = sift.detectAndCompute(ia, None)
    kb, db = sift.detectAndCompute(ib, None)
    good = [m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < 0.7 * n.distance]
    # OpenCV keypoints -> COLMAP pixels (+0.5), the convention of the loaded intrinsics.
    pa = np.array([ka[m.queryIdx].pt for m in good]) + 0.5
    pb = np.array([kb[m.trainIdx].pt for m in good]) + 0.5

    def k_matrix(name):
        fx, fy, cx, cy = scene.gt.cameras[name].intrinsics.params
        return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1]])

    na, nb = scene.camera_names[a], scene.camera_names[b]
    rel = scene.gt.cameras[nb].cam_from_rig @ np.linalg.inv(scene.gt.cameras[na].cam_from_rig)
    t = rel[:3, 3]
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    f = np.linalg.inv(k_matrix(nb)).T @ tx @ rel[:3, :3] @ np.linalg.inv(k_matrix(na))
    lines = np.c_[pa, np.ones(len(pa))] @ f.T
    return np.abs(np.sum(lines * np.c_[pb, np.ones(len(pb))], 1)) / np.linalg.norm(lines[:, :2], axis=1)


@needs_strecha
def test_strecha_loader_scales_and_is_consistent():
    scene = load_strecha(STRECHA, max_side_px=768)
    assert scene.camera_names == [f"{k:04d}" for k in range(10)]
    assert len(scene.frame_sets) == 1 and len(scene.frame_sets[0]) == 10
    img = scene.frame_sets[0][0]
    assert img.shape == (512, 768, 3) and img.dtype == np.uint8
    cam0 = scene.gt.cameras["0000"].intrinsics
    assert (cam0.model, cam0.width, cam0.height) == ("PINHOLE", 768, 512)
    # K.txt: fx=2759.48 fy=2764.16 cx=1520.69 cy=1006.81 at 3072x2048; COLMAP pp = (c + 0.5) * s.
    np.testing.assert_allclose(cam0.params, [2759.48 / 4, 2764.16 / 4, 1521.19 / 4, 1007.31 / 4])
    # Camera centre from cam_from_world equals the file's C.
    t = scene.gt_cam_from_world["0000"]
    np.testing.assert_allclose(-t[:3, :3].T @ t[:3, 3], [-4.11244, -2.19149, 0.221573], atol=1e-9)
    assert scene.gt.reference_camera == "0000"
    np.testing.assert_allclose(scene.gt.cameras["0000"].cam_from_rig, np.eye(4), atol=1e-12)
    # Real matches lie on the reference epipolar lines (sub-pixel): K, poses and scaling agree.
    d = _epipolar_distances_px(scene, 0, 1)
    assert len(d) > 200
    assert np.median(d) < 0.3
    assert np.mean(d < 2.0) > 0.8


def test_generated_folder_round_trip(tmp_path):
    from densecalib_ros.eval.datasets import load_generated, scene_from_synthetic
    from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig

    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, width=160, height=120, num_time_steps=2,
                               supersample=1, seed=3))
    write_rig(rig, tmp_path / "rig")
    scene = load_generated(tmp_path / "rig")
    direct = scene_from_synthetic(rig, "rig")
    assert scene.camera_names == direct.camera_names == ["cam0", "cam1", "cam2"]
    assert len(scene.frame_sets) == 2 and scene.lens == "pinhole"
    np.testing.assert_array_equal(scene.frame_sets[1][2], rig.images[1][2])  # PNG is lossless
    for name in scene.camera_names:
        np.testing.assert_allclose(scene.gt.cameras[name].cam_from_rig,
                                   direct.gt.cameras[name].cam_from_rig, atol=1e-9)
        np.testing.assert_allclose(scene.gt.cameras[name].intrinsics.params,
                                   direct.gt.cameras[name].intrinsics.params)


FOX = default_data_dir() / "ngp_fox"


@pytest.mark.skipif(not (FOX / "transforms.json").is_file(),
                    reason=f"instant-ngp fox not found at {FOX} (set DENSECALIB_DATA to the shared "
                           "data dir)")
def test_nerf_loader_axes_and_intrinsics_agree_with_the_images():
    from densecalib_ros.eval.datasets import load_nerf_transforms

    scene = load_nerf_transforms(FOX, num_views=25, max_side_px=1024)
    assert len(scene.camera_names) == 25 and scene.reference_is_estimate
    cam = scene.gt.cameras[scene.camera_names[0]].intrinsics
    assert (cam.model, cam.width, cam.height) == ("OPENCV", 576, 1024)
    s = 1024 / 1920  # transforms.json: fl_x 1375.52, cx 554.558 at 1080x1920
    np.testing.assert_allclose(cam.params[[0, 2]], [1375.52 * s, 555.058 * s], rtol=1e-9)
    # SIFT matches of neighbouring frames lie on the epipolar lines of the reference poses once
    # undistorted: the OpenGL -> OpenCV axis flip, the pose inversion and the scaling are right.
    sift = cv2.SIFT_create(4000)
    gray = [cv2.cvtColor(scene.frame_sets[0][k], cv2.COLOR_RGB2GRAY) for k in (0, 1)]
    (ka, da), (kb, db) = (sift.detectAndCompute(g, None) for g in gray)
    good = [m for m, n in cv2.BFMatcher().knnMatch(da, db, k=2) if m.distance < 0.7 * n.distance]
    fx, fy, cx, cy, *dist = cam.params
    K = np.array([[fx, 0, cx - 0.5], [0, fy, cy - 0.5], [0, 0, 1]])  # OpenCV pixel convention
    pa, pb = (cv2.undistortPoints(np.array([kp[i].pt for i in idx], np.float64)[:, None], K,
                                  np.array(dist)).reshape(-1, 2)
              for kp, idx in ((ka, [m.queryIdx for m in good]), (kb, [m.trainIdx for m in good])))
    na, nb = scene.camera_names[:2]
    rel = scene.gt.cameras[nb].cam_from_rig @ np.linalg.inv(scene.gt.cameras[na].cam_from_rig)
    t = rel[:3, 3] / np.linalg.norm(rel[:3, 3])
    E = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ rel[:3, :3]
    lines = np.c_[pa, np.ones(len(pa))] @ E.T
    d_px = fx * np.abs(np.sum(lines * np.c_[pb, np.ones(len(pb))], 1)) / np.linalg.norm(
        lines[:, :2], axis=1)
    assert len(d_px) > 100
    assert np.median(d_px) < 1.0


CALISCOPE = default_data_dir() / "caliscope_4webcams"
MEVA = default_data_dir() / "meva_6cam_surveillance"


def _reprojection_px(scene, name, world_xyz, observed_opencv_px):
    """Distances (px) of world points projected with the loaded reference camera `name` from their
    observed OpenCV pixels (+0.5: COLMAP's convention, that of the loaded intrinsics)."""
    pose = scene.gt_cam_from_world[name]
    cam_xyz = world_xyz @ pose[:3, :3].T + pose[:3, 3]
    projected = scene.gt.cameras[name].intrinsics.to_pycolmap().img_from_cam(cam_xyz)
    return np.linalg.norm(projected - (observed_opencv_px + 0.5), axis=1)


@pytest.mark.skipif(not (CALISCOPE / "camera_array.toml").is_file(),
                    reason=f"Caliscope's session not found at {CALISCOPE} (set DENSECALIB_DATA)")
def test_caliscope_loader_reference_reprojects_the_boards_corners():
    """The loaded reference (K, k1 k2 p1 p2 k3 as FULL_OPENCV, world -> camera poses) puts
    Caliscope's triangulated ChArUco corners on its detections: about 1 px median per camera, as
    its source notes measured; the frame sets come from the videos as `calibrate --videos` reads
    them."""
    import csv

    from densecalib_ros.eval.datasets import load_caliscope

    scene = load_caliscope(CALISCOPE, num_sets=2)
    assert scene.camera_names == ["cam_0", "cam_1", "cam_2", "cam_3"]
    assert len(scene.frame_sets) == 2 and scene.frame_sets[0][0].shape == (720, 1280, 3)
    focal = [scene.gt.cameras[n].intrinsics.params[0] for n in scene.camera_names]
    assert np.allclose(focal, [904, 760, 651, 640], atol=1.0)
    folder = CALISCOPE / "calibration" / "extrinsic" / "CHARUCO"
    with open(folder / "xyz_CHARUCO.csv") as f:
        world = {(r["sync_index"], r["keypoint_id"]): [float(r[k]) for k in
                                                      ("x_coord", "y_coord", "z_coord")]
                 for r in csv.DictReader(f)}
    with open(folder / "xy_CHARUCO.csv") as f:
        rows = [r for r in csv.DictReader(f) if (r["sync_index"], r["keypoint_id"]) in world]
    for cam_id, name in enumerate(scene.camera_names):
        mine = [r for r in rows if int(r["cam_id"]) == cam_id]
        xyz = np.array([world[(r["sync_index"], r["keypoint_id"])] for r in mine])
        px = np.array([[float(r["img_loc_x"]), float(r["img_loc_y"])] for r in mine])
        assert len(mine) > 50 and np.median(_reprojection_px(scene, name, xyz, px)) < 2.0, name


@pytest.mark.skipif(not (MEVA / "cameras").is_dir(),
                    reason=f"MEVA's cameras not found at {MEVA} (set DENSECALIB_DATA)")
def test_krtd_loader_reference_reprojects_the_annotated_landmarks():
    """MEVA's KRTD models as loaded put the hand-annotated landmarks (landmarks.ply) on their
    annotations (tracks.txt, camera n = line n of frames.txt) within a fraction of a pixel at the
    median, as its source notes measured; cameras without a still are left out."""
    from densecalib_ros.eval.datasets import load_krtd_stills

    scene = load_krtd_stills(MEVA)
    assert scene.camera_names == ["G328", "G341", "G424", "G436", "G505", "G506"]
    assert [f.shape[0] for f in scene.frame_sets[0]] == [1072, 1080, 1080, 1080, 1072, 1072]
    lines = (MEVA / "landmarks.ply").read_text().splitlines()
    body = lines[lines.index("end_header") + 1:]
    landmarks = {int(v[9]): [float(x) for x in v[:3]] for v in (line.split() for line in body)}
    camera_of_index = {n + 1: path.split("/")[-1][:-4] for n, path in
                       enumerate((MEVA / "frames.txt").read_text().split())}
    observed: dict = {}
    for line in (MEVA / "tracks.txt").read_text().splitlines():
        track, index, x, y = line.split()[:4]
        name = camera_of_index[int(index)]
        if int(track) in landmarks and name in scene.camera_names:
            observed.setdefault(name, []).append((landmarks[int(track)], (float(x), float(y))))
    assert set(observed) == set(scene.camera_names)
    for name, pairs in observed.items():
        xyz = np.array([p[0] for p in pairs])
        px = np.array([p[1] for p in pairs])
        assert np.median(_reprojection_px(scene, name, xyz, px)) < 1.0, name


POSE2SIM = default_data_dir() / "pose2sim_4cam_ring"


@pytest.mark.skipif(not (POSE2SIM / "calibration" / "Calib.qca.txt").is_file(),
                    reason=f"Pose2Sim's demo ring not found at {POSE2SIM} (set DENSECALIB_DATA)")
def test_qualisys_loader_scales_letterboxed_videos_and_sees_the_platform():
    """Qualisys units (1/64 px, mm, y-up camera axes) as loaded: cam01's centre and viewing
    direction as the set's notes give them; the 1080-wide letterboxed videos get K scaled by
    1080/1088 and shifted by the letterbox; the force platform's ends (Config.toml, world m) lie
    in front of every camera and inside its image (the set ships no 2D points to measure)."""
    from densecalib_ros.eval.datasets import load_qualisys_videos

    scene = load_qualisys_videos(POSE2SIM, num_sets=1)
    assert scene.camera_names == ["cam01", "cam02", "cam03", "cam04"]
    cam01 = scene.gt.cameras["cam01"].intrinsics
    assert (cam01.width, cam01.height) == (1080, 1920)
    assert cam01.params[0] == pytest.approx(107599.671875 / 64 * 1080 / 1088)
    assert cam01.params[3] == pytest.approx((60680.792969 / 64 + 0.5) * 1080 / 1088
                                            + (1920 - 1920 * 1080 / 1088) / 2)
    assert scene.gt.cameras["cam03"].intrinsics.width == 1088
    pose = scene.gt_cam_from_world["cam01"]
    assert np.allclose(-pose[:3, :3].T @ pose[:3, 3], [1.460, -1.909, 1.897], atol=1e-3)
    assert np.allclose(pose[2, :3], [-0.71, 0.59, -0.38], atol=0.01)
    platform = np.array([(-2.0, 0.3, 0), (-2.0, 0, 0), (-2.0, 0, 0.05), (-2.0, -0.3, 0),
                         (0, 0.3, 0), (0, 0, 0), (0, 0, 0.05), (0, -0.3, 0)])
    for name in scene.camera_names:
        pose = scene.gt_cam_from_world[name]
        xyz = platform @ pose[:3, :3].T + pose[:3, 3]
        cam = scene.gt.cameras[name].intrinsics
        uv = cam.to_pycolmap().img_from_cam(xyz)
        assert np.all(xyz[:, 2] > 1.0), name
        assert np.all((uv > 0) & (uv < [cam.width, cam.height])), name
