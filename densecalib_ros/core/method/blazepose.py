"""BlazePose's pre- and post-processing as MediaPipe's legacy pose solution (0.10.x) runs it,
in NumPy and OpenCV: the detector's letterboxed input, its SSD anchors, decoding and weighted
non-max suppression, the person's rotated region of interest (ROI), the landmark model's crop of
it, and the landmarks mapped back to the image. The models themselves run in
core.method.person_keypoints.

Coordinates: `image_xy` are continuous pixel coordinates with (0, 0) at the top-left corner of
the top-left pixel (MediaPipe's normalised coordinates times the image size); OpenCV's pixel
convention, (0, 0) at the top-left pixel's centre, is image_xy - 0.5.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# --- Detector (mediapipe/modules/pose_detection/pose_detection_cpu.pbtxt, 0.10.x) ---
# The model's input side (pose_detection.tflite: input 1x224x224x3, read at load).
DETECTOR_SIZE_PX = 224
# SsdAnchorsCalculator options of that graph: 5 layers with these strides (the last three share
# a 7x7 grid), aspect ratio 1 plus the interpolated one -> 2 anchors per layer and cell, fixed
# unit size: 28*28*2 + 14*14*2 + 7*7*6 = 2254 anchors, the model's 2254 outputs.
ANCHOR_STRIDES = (8, 16, 32, 32, 32)
ANCHORS_PER_LAYER_AND_CELL = 2
# TensorsToDetectionsCalculator: scores are clipped logits (score_clipping_thresh 100) through a
# sigmoid; 12 values per box: x, y, w, h (reverse_output_order) then 4 keypoints' x, y, all in
# 224-px tensor units relative to the anchor centre.
SCORE_CLIP_LOGIT = 100.0
# NonMaxSuppressionCalculator: WEIGHTED algorithm, boxes suppressed above this IoU.
NMS_MIN_IOU = 0.3
# The detection's keypoints (pose_detection_cpu.pbtxt): 0 mid-hip centre, 1 a point whose
# distance and direction from it give the full body's size and rotation.
KP_HIP_CENTRE, KP_BODY_SCALE = 0, 1

# --- ROI (mediapipe/modules/pose_landmark/pose_detection_to_roi.pbtxt, 0.8.4 and later) ---
# AlignmentPointsRectsCalculator: rotation_vector_target_angle_degrees 90 (the body upright);
# the rect's side is twice the keypoints' distance; RectTransformationCalculator scale_x = scale_y
# = 1.25 with square_long: the margin the landmark model was trained with.
ROI_TARGET_ANGLE_RAD = np.pi / 2
ROI_SCALE = 1.25

# --- Landmarks (pose_landmark_by_roi_cpu.pbtxt, tensors_to_pose_landmarks_and_segmentation) ---
# Output 0: 39 landmarks x (x, y, z, visibility logit, presence logit), x and y in 256-px tensor
# units; the first 33 are the body's, 33-34 auxiliary (the next frame's ROI, unused here).
NUM_LANDMARKS_OUT = 39
NUM_BODY_LANDMARKS = 33
# RefineLandmarksFromHeatmapCalculator: kernel_size 7 (options), min_confidence_to_refine 0.5
# (its proto default): a landmark moves to the sigmoid-weighted mean of its 7x7 heatmap window
# when the window's peak is at least that confident.
HEATMAP_KERNEL = 7
HEATMAP_MIN_CONFIDENCE = 0.5


def sigmoid(x: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.asarray(x, np.float64)))


def ssd_anchor_centres(size_px: int = DETECTOR_SIZE_PX) -> np.ndarray:
    """(N, 2) anchor centres (x, y) normalised to the tensor, in the order of the detector's
    outputs (SsdAnchorsCalculator: per group of layers of equal stride, rows, columns, then the
    anchors of the cell). With fixed_anchor_size every anchor is 1 x 1, so only centres matter."""
    centres, layer = [], 0
    while layer < len(ANCHOR_STRIDES):
        stride = ANCHOR_STRIDES[layer]
        same = next((k for k in range(layer, len(ANCHOR_STRIDES))
                     if ANCHOR_STRIDES[k] != stride), len(ANCHOR_STRIDES)) - layer
        cells = int(np.ceil(size_px / stride))
        ys, xs = np.meshgrid((np.arange(cells) + 0.5) / cells, (np.arange(cells) + 0.5) / cells,
                             indexing="ij")
        grid = np.stack([xs.ravel(), ys.ravel()], axis=1)
        centres.append(np.repeat(grid, same * ANCHORS_PER_LAYER_AND_CELL, axis=0))
        layer += same
    return np.concatenate(centres)


@dataclass
class Letterbox:
    """How an image was fitted into the square detector input: tensor_px = image_xy * scale +
    offset (per axis, continuous coordinates of both)."""

    scale_xy: np.ndarray  # (2,)
    offset_xy: np.ndarray  # (2,) tensor px

    def to_image(self, tensor_px: np.ndarray) -> np.ndarray:
        return (np.asarray(tensor_px, float) - self.offset_xy) / self.scale_xy


def letterbox(image: np.ndarray, size_px: int = DETECTOR_SIZE_PX
              ) -> tuple[np.ndarray, Letterbox]:
    """(size, size, 3) float32 in [-1, 1] (ImageToTensorCalculator: keep_aspect_ratio,
    BORDER_ZERO, range -1..1) and its Letterbox. The image is shrunk with area averaging, which
    does not alias as a bilinear warp does at the 5-10x reductions of camera images."""
    import cv2

    height, width = image.shape[:2]
    fit = size_px / max(width, height)
    new_w, new_h = max(1, int(round(width * fit))), max(1, int(round(height * fit)))
    small = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_AREA if fit < 1
                       else cv2.INTER_LINEAR)
    left, top = (size_px - new_w) // 2, (size_px - new_h) // 2
    tensor = np.full((size_px, size_px, 3), -1.0, np.float32)  # zero pixels are -1 in range
    tensor[top:top + new_h, left:left + new_w] = small.astype(np.float32) / 127.5 - 1.0
    return tensor, Letterbox(np.array([new_w / width, new_h / height]),
                             np.array([float(left), float(top)]))


@dataclass
class PoseDetection:
    """One detected person: score in [0, 1], face box (x0, y0, x1, y1) and the 4 alignment
    keypoints (4, 2), in image_xy (module docstring)."""

    score: float
    box_xyxy: np.ndarray
    keypoints_xy: np.ndarray


def decode_detections(raw_boxes: np.ndarray, raw_scores: np.ndarray, anchors: np.ndarray,
                      min_score: float, size_px: int = DETECTOR_SIZE_PX
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(scores (K,), boxes (K, 4) x0 y0 x1 y1, keypoints (K, 4, 2)) in tensor px of the anchors
    scoring at least min_score; raw_boxes (N, 12), raw_scores (N,) logits."""
    scores = sigmoid(np.clip(raw_scores.reshape(-1), -SCORE_CLIP_LOGIT, SCORE_CLIP_LOGIT))
    keep = np.flatnonzero(scores >= min_score)
    raw = raw_boxes.reshape(len(anchors), -1)[keep].astype(np.float64)
    centre_px = anchors[keep] * size_px
    cxcy = raw[:, 0:2] + centre_px
    half = raw[:, 2:4] / 2
    boxes = np.concatenate([cxcy - half, cxcy + half], axis=1)
    keypoints = raw[:, 4:12].reshape(-1, 4, 2) + centre_px[:, None, :]
    return scores[keep], boxes, keypoints


def iou(box: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Intersection over union of one box (x0, y0, x1, y1) with each of boxes (K, 4)."""
    lo = np.maximum(box[:2], boxes[:, :2])
    hi = np.minimum(box[2:], boxes[:, 2:])
    inter = np.prod(np.clip(hi - lo, 0, None), axis=1)
    union = _area(box) + _area(boxes) - inter
    return np.where(union > 0, inter / np.maximum(union, 1e-12), 0.0)


def _area(boxes: np.ndarray) -> np.ndarray:
    return np.prod(np.clip(boxes[..., 2:] - boxes[..., :2], 0, None), axis=-1)


def weighted_nms(scores: np.ndarray, boxes: np.ndarray, keypoints: np.ndarray,
                 min_iou: float = NMS_MIN_IOU) -> list[tuple[float, np.ndarray, np.ndarray]]:
    """MediaPipe's WEIGHTED non-max suppression: from the best remaining detection, every one
    overlapping it above min_iou is merged into it (box and keypoints averaged with the scores
    as weights; the best score kept) and removed. Best first."""
    order = list(np.argsort(-scores, kind="stable"))
    out = []
    while order:
        best = order[0]
        overlap = iou(boxes[best], boxes[order]) > min_iou
        group = [order[k] for k in np.flatnonzero(overlap)]
        w = scores[group] / scores[group].sum()
        out.append((float(scores[best]), (w[:, None] * boxes[group]).sum(0),
                    (w[:, None, None] * keypoints[group]).sum(0)))
        order = [order[k] for k in np.flatnonzero(~overlap)]
    return out


@dataclass
class PoseRoi:
    """A square, rotated region of interest around a person: centre (image_xy), side (px) and
    rotation (rad; positive turns the crop's axes clockwise on the image, y pointing down)."""

    centre_xy: np.ndarray
    side_px: float
    rotation_rad: float

    def crop_from_image(self, crop_px: int) -> np.ndarray:
        """2x3 affine taking image_xy to the crop's continuous pixel coordinates."""
        return np.linalg.inv(np.vstack([self.image_from_crop(crop_px), [0, 0, 1]]))[:2]

    def image_from_crop(self, crop_px: int) -> np.ndarray:
        """2x3 affine taking the crop's continuous px (0..crop_px) to image_xy: MediaPipe's
        LandmarkProjectionCalculator, ((u / crop_px - 0.5) rotated, times the side, plus the
        centre)."""
        c, s = np.cos(self.rotation_rad), np.sin(self.rotation_rad)
        linear = self.side_px / crop_px * np.array([[c, -s], [s, c]])
        return np.hstack([linear, (self.centre_xy - linear @ [crop_px / 2, crop_px / 2])[:, None]])


def roi_from_detection(keypoints_xy: np.ndarray) -> PoseRoi:
    """The landmark model's ROI from a detection's alignment keypoints (image_xy):
    AlignmentPointsRectsCalculator then RectTransformationCalculator (constants above)."""
    centre = keypoints_xy[KP_HIP_CENTRE]
    towards = keypoints_xy[KP_BODY_SCALE] - centre
    side = 2.0 * float(np.hypot(*towards)) * ROI_SCALE
    rotation = ROI_TARGET_ANGLE_RAD - np.arctan2(-towards[1], towards[0])
    rotation = rotation - 2 * np.pi * np.floor((rotation + np.pi) / (2 * np.pi))
    return PoseRoi(np.asarray(centre, float), side, float(rotation))


def crop(image: np.ndarray, roi: PoseRoi, crop_px: int) -> np.ndarray:
    """(crop_px, crop_px, 3) uint8 of the ROI, its axes along the ROI's (ImageToTensorCalculator
    with a rotated rect; its default BORDER_REPLICATE outside the image). A ROI much larger than
    the crop is sampled from an area-averaged smaller copy of the image, so it does not alias."""
    import cv2

    shrink = min(1.0, crop_px / max(roi.side_px, 1e-6))
    source, image_scale = image, np.ones(2)
    if shrink < 0.75:  # more than 4:3 down: average areas first
        h, w = image.shape[:2]
        size = (max(1, int(round(w * shrink))), max(1, int(round(h * shrink))))
        source = cv2.resize(image, size, interpolation=cv2.INTER_AREA)
        image_scale = np.array([size[0] / w, size[1] / h])
    # continuous crop px -> continuous source px, then both to OpenCV's centre convention
    to_source = np.diag(image_scale) @ roi.image_from_crop(crop_px)
    to_source = to_source + np.hstack([np.zeros((2, 2)), (to_source[:, :2] @ [0.5, 0.5]
                                                           - 0.5)[:, None]])
    return cv2.warpAffine(source, to_source, (crop_px, crop_px),
                          flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_REPLICATE)


def refine_from_heatmap(xy_norm: np.ndarray, heatmap: np.ndarray) -> np.ndarray:
    """(L, 2) landmarks (normalised to the crop) moved as RefineLandmarksFromHeatmapCalculator
    does, from the (h, w, L) heatmap logits: to the sigmoid-weighted mean cell of a 7x7 window
    around each, where the window's peak is confident, cell c read as c / w as MediaPipe reads
    it. (Measured on 16 pose2sim crops, 598 landmarks: that agrees with the regressed landmarks
    to -0.3 crop px on average; the cell's centre, (c + 0.5) / w, would be 1.7 px off.)"""
    out = np.array(xy_norm, np.float64)
    h, w, _ = heatmap.shape
    half = (HEATMAP_KERNEL - 1) // 2
    for k, (x, y) in enumerate(out):
        col, row = int(np.floor(x * w)), int(np.floor(y * h))
        if not (0 <= col < w and 0 <= row < h):
            continue
        rows = slice(max(0, row - half), min(h, row + half + 1))
        cols = slice(max(0, col - half), min(w, col + half + 1))
        conf = sigmoid(heatmap[rows, cols, k])
        if conf.max() < HEATMAP_MIN_CONFIDENCE or conf.sum() <= 0:
            continue
        rr, cc = np.mgrid[rows, cols]
        out[k] = (cc * conf).sum() / conf.sum() / w, (rr * conf).sum() / conf.sum() / h
    return out
