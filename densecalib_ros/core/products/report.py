"""The text report of a rig calibration: intrinsics and fit per camera, where the cameras sit in the
rig, and (optionally) how it differs from another calibration of the same cameras: a previous one,
or a ground truth. `densecalib calibrate` prints the camera table after a calibration;
`densecalib report` prints the whole report of a calibration on disk (e.g. the node's output), and
with --history one line per calibration a node's output_dir keeps."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import InputError
from ..io.calibration_store import LATEST, stored_calibrations
from ..io.export import read_calibration
from ..metrics import mean_focal_px
from ..monitor.change import CameraChange, calibration_change, change_summary, pose_agreement
from ..types import CameraIntrinsics, RigCalibration, RigQuality


def distortion_text(intrinsics: CameraIntrinsics) -> str:
    """The parameters after the principal point, named: "k1=-0.0512 k2=0.0104"."""
    names = intrinsics.parameter_names
    first = names.index("cy") + 1
    return " ".join(f"{n}={v:.4g}" for n, v in zip(names[first:], intrinsics.params[first:]))


def principal_point_px(intrinsics: CameraIntrinsics) -> tuple[float, float]:
    """(cx, cy) in OpenCV/ROS pixel coordinates (the centre of the top-left pixel is 0, 0), as
    every written file has them; COLMAP's params are 0.5 px more."""
    names = intrinsics.parameter_names
    return (float(intrinsics.params[names.index("cx")]) - 0.5,
            float(intrinsics.params[names.index("cy")]) - 0.5)


def focal_text(intrinsics: CameraIntrinsics) -> str:
    """The focal length (px): one number, or fx/fy where they differ (OPENCV, OPENCV_FISHEYE,
    PINHOLE models fit them apart)."""
    names = intrinsics.parameter_names
    if "fx" in names and "fy" in names:
        fx, fy = (float(intrinsics.params[names.index(k)]) for k in ("fx", "fy"))
        if abs(fx - fy) >= 0.05:
            return f"{fx:.1f}/{fy:.1f}"
    return f"{mean_focal_px(intrinsics):.1f}"


def camera_table(rig: RigCalibration) -> str:
    """Per camera: model, image size, focal (fx/fy where they differ) and its standard deviation,
    principal point (px, OpenCV convention as in the written files; its standard deviation where
    it was refined), the standard deviation of
    where a ray projects (proj_std: the intrinsics as a whole), distortion and the fit:
    reprojection RMS, observations (all / seen by >= 3 cameras) and the fraction of the image
    covered by observations. Standard deviations: core.method.uncertainty ('-' where not estimated,
    'given' for intrinsics the user gave and the calibration kept)."""
    given = set(rig.quality.given_intrinsics or ())
    focal_width = max([9] + [len(focal_text(c.intrinsics)) for c in rig.cameras.values()])
    rows = [f"{'camera':<16} {'model':<15} {'size':>9} {'focal_px':>{focal_width}} {'f_std':>6} "
            f"{'cx':>7} {'cy':>7} {'pp_std':>6} {'proj_std':>8} {'rms_px':>6} {'obs':>6} "
            f"{'obs3+':>6} {'coverage':>8}  distortion"]
    for name, cam in rig.cameras.items():
        k = cam.intrinsics
        cx, cy = principal_point_px(k)
        q = cam.quality
        if q is None:
            f_std, pp_std, proj_std = "-", "-", "-"
            fit = f"{'-':>6} {'-':>6} {'-':>6} {'-':>8}"
        else:
            f_std = _optional(q.focal_std_px, ".1f")
            pp_std = _optional(q.principal_point_std_px, ".1f")
            proj_std = _optional(q.projection_std_px, ".2f")
            fit = (f"{q.reprojection_rms_px:6.2f} {q.num_observations:6d} "
                   f"{_optional(q.num_multiview_observations, 'd'):>6} {q.coverage:8.2f}")
        if name in given:
            f_std, pp_std, proj_std = "given", "given", "given"
        rows.append(f"{name:<16} {k.model:<15} {f'{k.width}x{k.height}':>9} "
                    f"{focal_text(k):>{focal_width}} {f_std:>6} {cx:7.1f} {cy:7.1f} {pp_std:>6} "
                    f"{proj_std:>8} {fit}  {distortion_text(k)}")
    return "\n".join(rows)


def intrinsics_note(rig: RigCalibration) -> str:
    """Lines under the camera table on the principal points: which the images estimated and which
    were held at the image centre (core.method.image_refinement; their pp_std is how far a real
    lens's may be from there), or, for calibrations that held every pinhole camera's point
    (held_pp_std_fraction), that their sigmas include that offset. '' where there is nothing to
    say."""
    given = set(rig.quality.given_intrinsics or ())
    judged = {n: c.quality.estimated_intrinsics for n, c in rig.cameras.items()
              if n not in given and c.quality is not None
              and isinstance(c.quality.estimated_intrinsics, list)}
    if judged:
        lines = []
        estimated = [n for n, e in judged.items() if "cx" in e]
        held = [n for n, e in judged.items() if "cx" not in e]
        if estimated:
            lines.append(f"principal point estimated from the images: {', '.join(estimated)}")
        if held:
            lines.append(f"principal point held at the image centre (the images do not pin it "
                         f"down; pp_std is how far a real lens's may lie): {', '.join(held)}")
        aspect = [n for n, e in judged.items() if "aspect" in e]
        if aspect:
            lines.append(f"pixel aspect estimated (fx/fy): {', '.join(aspect)}")
        return "\n".join(lines)
    fraction = rig.quality.held_pp_std_fraction  # absent in files written before it
    held = [n for n, c in rig.cameras.items() if n not in given and c.quality is not None
            and c.quality.focal_std_px is not None and c.quality.principal_point_std_px is None]
    if not held or not fraction:
        return ""
    return (f"f_std and proj_std of {', '.join(held)} include where a real principal point may "
            f"lie: {100 * fraction:g} % of the long side (1 sigma per axis) from where the "
            "calibration held it")


def _optional(value, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def camera_centres_in_rig(rig: RigCalibration) -> dict[str, np.ndarray]:
    """Each camera's optical centre in the rig frame (the reference camera's optical frame)."""
    return {n: -c.cam_from_rig[:3, :3].T @ c.cam_from_rig[:3, 3] for n, c in rig.cameras.items()}


def layout_table(rig: RigCalibration) -> str:
    """Where each camera is in the rig frame (x right, y down, z forward of the reference camera):
    optical centre, its distance from the reference, and the angle between its optical axis and
    the reference's. Units are metres when the scale came from a known baseline, else the
    reconstruction's arbitrary unit."""
    unit = "m" if rig.metric_scale else "units"
    rows = [f"{'camera':<16} {f'x_{unit}':>9} {f'y_{unit}':>9} {f'z_{unit}':>9} "
            f"{f'dist_{unit}':>10} {'axis_deg':>8}"]
    for name, centre in camera_centres_in_rig(rig).items():
        centre = np.round(centre, 3) + 0.0  # no "-0.000"
        axis_in_rig = rig.cameras[name].cam_from_rig[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        axis_deg = float(np.degrees(np.arccos(np.clip(axis_in_rig[2], -1.0, 1.0))))
        rows.append(f"{name:<16} {centre[0]:9.3f} {centre[1]:9.3f} {centre[2]:9.3f} "
                    f"{np.linalg.norm(centre):10.3f} {axis_deg:8.2f}")
    return "\n".join(rows)


def change_table(change: dict[str, CameraChange]) -> str:
    """Per camera in both calibrations: focal change (%), the median over its camera pairs of the
    relative rotation and translation-direction changes (deg), and the mean projection change
    (px) of its intrinsics."""
    rows = [f"{'camera':<16} {'focal_%':>8} {'rot_deg':>8} {'dir_deg':>8} {'proj_px':>8}"]
    for name, c in change.items():
        proj = "-" if c.projection_change_px is None else f"{c.projection_change_px:.2f}"
        rows.append(f"{name:<16} {c.focal_change_pct:+8.2f} {c.rotation_change_deg:8.3f} "
                    f"{c.translation_dir_change_deg:8.3f} {proj:>8}")
    return "\n".join(rows)


def info_strips_line(quality: RigQuality) -> str:
    """The info strips a calibration ignored (quality.info_strips), as one line."""
    return "info strips ignored: " + ", ".join(
        f"{n} {what}" for n, what in (quality.info_strips or {}).items())


def overall_lines(rig: RigCalibration) -> list[str]:
    """What the calibration was made from and how well it fits, from rig.quality (older or
    hand-written files may lack some of it)."""
    q = rig.quality
    made = [f"{value} {label}" for value, label in ((q.pipeline, "pipeline"), (q.preset, "preset"),
                                                    (q.matcher, "matcher")) if value is not None]
    if q.num_frame_sets is not None:
        made.append(f"{q.num_frame_sets} frame set(s)")
    if q.camera_lens:
        made.append("lenses " + ", ".join(f"{n} {lens}" for n, lens in q.camera_lens.items()))
    lines = [f"{len(rig.cameras)} camera(s), reference {rig.reference_camera}"
             + (f"; {', '.join(made)}" if made else "")]
    source = q.input or {}
    if source:
        where = ", ".join(source.get("topics", [])) if source.get("source") == "topics" \
            else source.get("path", "?")
        lines.append(f"from {source.get('source', '?')} {where}"
                     + (f", densecalib {q.densecalib_version}" if q.densecalib_version else "")
                     + (f", {q.calibrated_utc}" if q.calibrated_utc else ""))
        offsets = source.get("time_offsets_s") or source.get("stamp_offsets_s")
        if offsets:
            estimated = source.get("time_offsets_estimated") or {}
            reference = next(iter(estimated), None)

            def how(name):  # the evidence behind an estimated offset
                e = estimated.get(name) if name != reference else None
                if not e:
                    return ""
                return (f" (correlation {e['correlation']:.2f})" if "correlation" in e
                        else f" ({e['paired_shots']} shots paired)")
            found = ("" if not estimated else " (found from the capture times)"
                     if "paired_shots" in estimated[reference] else
                     " (found from the images' motion)")
            lines.append("time offsets (s, ahead of the others): " + ", ".join(
                f"{n} {float(o):+.3f}{how(n)}" for n, o in offsets.items()) + found)
    fit = []
    if q.reprojection_rms_px is not None:
        fit.append(f"reprojection RMS {float(q.reprojection_rms_px):.2f} px")
    if q.num_points is not None:
        fit.append(f"{q.num_points} points")
    if q.consensus_runs == 1 and q.consensus_settled_starts and not q.consensus_failed_runs:
        fit.append("one run: every focal start that fit as well ended in its rig")
    elif q.consensus_disagreement_deg is not None:
        refined = q.consensus_refined_disagreement_deg
        fit.append(f"runs disagree by {float(q.consensus_disagreement_deg):.2f} deg" + (
            f" ({float(refined):.2f} deg refined on dense correspondences)"
            if refined is not None else ""))
    if fit:
        lines.append(", ".join(fit))
    if rig.failed_cameras:
        lines.append("not registered: " + ", ".join(rig.failed_cameras))
    if q.info_strips:
        lines.append(info_strips_line(q))
    for warning in q.warnings:
        lines.append(f"warning: {warning}")
    if q.change_summary is not None:
        lines.append(f"{q.change_summary} (started {q.init or '?'})")
    if q.floor:
        lines.append(format_floor(rig))
    baseline, points = q.scale_from_baseline, q.scale_from_points
    lines.append(f"scale: metric, from the {baseline['baseline_m']} m baseline "
                 f"{baseline['cameras'][0]}-{baseline['cameras'][1]}"
                 if rig.metric_scale and baseline
                 else f"scale: metric, from {points['distance_m']:.4g} m between two scene points "
                 f"(1 sigma {100 * points['relative_std']:.2g} %)" if rig.metric_scale and points
                 else "scale: metric" if rig.metric_scale
                 else "scale: arbitrary (no known baseline or distance was given)")
    return lines


def rig_report(rig: RigCalibration, against: Optional[RigCalibration] = None,
               against_label: str = "the other calibration") -> str:
    """The whole report: overall lines, camera table, layout and, with `against`, the change
    from it and the pose agreement with it."""
    note = intrinsics_note(rig)
    parts = ["\n".join(overall_lines(rig)), "", camera_table(rig) + (f"\n{note}" if note else ""),
             "",
             "camera layout in the rig frame (reference camera's optical frame: x right, y down, "
             "z forward)", layout_table(rig)]
    if against is not None:
        parts += ["", f"change from {against_label}",
                  change_table(calibration_change(against, rig))]
        agreement = pose_agreement(against, rig)
        parts.append(f"relative-pose agreement with {against_label} over its "
                     f"{agreement['num_pairs']} camera pair(s): AUC@3 {agreement['auc3']:.1f}, "
                     f"AUC@30 {agreement['auc30']:.1f}")
        only_here = [n for n in rig.cameras if n not in against.cameras]
        only_there = [n for n in against.cameras if n not in rig.cameras]
        if only_here:
            parts.append(f"not in {against_label}: {', '.join(only_here)}")
        if only_there:
            parts.append(f"missing from this calibration: {', '.join(only_there)}")
    return "\n".join(parts)


def format_floor(rig: RigCalibration) -> str:
    """One line on the floor recorded in rig.quality.floor (core.products.floor)."""
    floor = rig.quality.floor
    unit = "m" if rig.metric_scale else "units"
    return (f"floor: {floor['num_points']} points within {floor['rms']:.3g} {unit} (rms); camera "
            "heights " + ", ".join(f"{n} {h:.3g}" for n, h in floor["camera_heights"].items())
            + f" {unit}")


def history_rows(root: str | Path) -> list[dict]:
    """The calibrations stored in a node's output_dir (core.io.calibration_store), oldest first:
    {"name", "latest", "cameras", "failed", "reprojection_rms_px", "change"} with "change" the
    one-line change from the readable one before it (core.monitor.change), or {"name", "error"} for
    one that cannot be read."""
    root = Path(root)
    latest = (root / LATEST).resolve() if (root / LATEST).exists() else None
    rows, previous = [], None
    for folder in stored_calibrations(root):
        try:
            rig = read_calibration(folder)
        except InputError as exc:
            rows.append({"name": folder.name, "error": str(exc)})
            continue
        rows.append({"name": folder.name, "latest": folder.resolve() == latest,
                     "cameras": list(rig.cameras), "failed": list(rig.failed_cameras),
                     "reprojection_rms_px": rig.quality.reprojection_rms_px,
                     "change": (change_summary(calibration_change(previous, rig), prefix="")
                                if previous is not None else None)})
        previous = rig
    return rows


def history_report(rows: list[dict]) -> str:
    """history_rows as text: one line per calibration, the one `latest` points to marked *."""
    lines = [f"  {'calibration':<20} {'cameras':>7} {'rms_px':>6}  change since the one before"]
    for row in rows:
        if "error" in row:
            lines.append(f"  {row['name']:<20} unreadable: {row['error']}")
            continue
        cameras = f"{len(row['cameras'])}/{len(row['cameras']) + len(row['failed'])}"
        lines.append(f"{'*' if row['latest'] else ' '} {row['name']:<20} {cameras:>7} "
                     f"{_optional(row['reprojection_rms_px'], '.2f'):>6}  "
                     f"{row['change'] or '(the first kept)'}")
    return "\n".join(lines) + "\n* = latest"
