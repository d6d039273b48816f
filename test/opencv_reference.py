"""OpenCV's own projection, the reference that files for and from OpenCV-based tools (anipose,
Kalibr, OpenCV's calibration samples) are checked against. Imported as `opencv_reference`
(pytest puts test/ on sys.path)."""
import cv2
import numpy as np


def opencv_pixels(pts, K, D, fisheye, rvec=np.zeros(3), tvec=np.zeros(3)) -> np.ndarray:
    """(N, 2) OpenCV pixels (top-left pixel centre at (0, 0)) of (N, 3) points, projected by
    cv2.projectPoints or cv2.fisheye.projectPoints with camera matrix K and distortion D."""
    pts = np.ascontiguousarray(np.asarray(pts, dtype=np.float64).reshape(-1, 1, 3))
    project = cv2.fisheye.projectPoints if fisheye else cv2.projectPoints
    out, _ = project(pts, np.asarray(rvec, float), np.asarray(tvec, float),
                     np.asarray(K, float), np.asarray(D, float))
    return out.reshape(-1, 2)
