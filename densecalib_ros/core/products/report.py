"""The text report of a rig calibration: intrinsics and fit per camera, where the cameras sit in the
rig, and (optionally) how it differs from another calibration of the same cameras: a previous one,
or a ground truth. `densecalib calibrate` prints the camera table after a calibration;
`densecalib report` prints the whole report of a calibration on disk (e.g. the node's output), and
with --history one line per calibration a node's output_dir keeps."""
from __future__ import annotations

import textwrap
from enum import Enum
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..errors import InputError
from ..io.calibration_store import LATEST, stored_calibrations
from ..io.export import read_calibration
from ..metrics import mean_focal_px
from ..method.uncertainty import CROPPED_FRAME_PP_STD_FRACTION
from ..monitor.change import CameraChange, calibration_change, change_summary, pose_agreement
from ..types import CameraIntrinsics, RigCalibration, RigQuality


# The width the camera table and its notes keep to: a terminal's (the aim), wide enough
# for the intrinsics' ten columns with a 21-character model name and an 8-character camera name.
TABLE_COLUMNS = 100
NAME_COLUMNS = (8, 24)  # the camera column's width: at least, at most (longer names shortened)
SHORTENED = "~"  # marks where a shortened camera name lost its middle (ASCII: any terminal)


class PrincipalPoint(str, Enum):
    """How a camera's principal point was decided (principal_point_case); the value is what the
    camera table's pp_from column prints."""

    ESTIMATED = "images"  # estimated from the images (image refinement's folds, or the final BA)
    PRIOR = "prior"  # not pinned down: resting on its prior, between the images' estimate and it
    CENTRE = "centre"  # held exactly at the image centre (a final BA that did not refine it)
    HELD = "held"  # held elsewhere, where the calibration started it
    GIVEN = "given"  # the user's (--intrinsics), kept
    UNKNOWN = "-"  # the file does not say (a ground truth, a hand-written file)


def principal_point_case(rig: RigCalibration, name: str) -> PrincipalPoint:
    """How camera `name`'s principal point was decided, from what the calibration recorded:
    given intrinsics; the image refinement's verdict (quality.estimated_intrinsics: "cx" listed
    where the images determined it, else it rests on its prior: core.method.image_refinement);
    held, exactly at the image centre or where it started, where the calibration recorded that a
    final bundle adjustment held it (quality.principal_point_held); in files that do not, a
    standard deviation where that adjustment refined it, else held."""
    cam = rig.cameras[name]
    quality = cam.quality
    if name in set(rig.quality.given_intrinsics or ()):
        return PrincipalPoint.GIVEN
    if quality is not None and isinstance(quality.estimated_intrinsics, list):
        return PrincipalPoint.ESTIMATED if "cx" in quality.estimated_intrinsics \
            else PrincipalPoint.PRIOR
    if quality is not None and quality.principal_point_held:  # with a sigma of the held point
        return PrincipalPoint.HELD if any(principal_point_offset_px(cam.intrinsics)) \
            else PrincipalPoint.CENTRE
    if quality is not None and quality.principal_point_std_px is not None:
        return PrincipalPoint.ESTIMATED
    if quality is None:  # not a calibration's own record (a ground truth, a hand-written file)
        return PrincipalPoint.UNKNOWN
    if not any(principal_point_offset_px(cam.intrinsics)):
        return PrincipalPoint.CENTRE
    # where the final adjustment held it, no sigma of its own; where there are none at all, the
    # file does not say
    return PrincipalPoint.HELD if quality.focal_std_px is not None else PrincipalPoint.UNKNOWN


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


def principal_point_offset_px(intrinsics: CameraIntrinsics) -> tuple[float, float]:
    """(dx, dy) px of the principal point from the image centre (the same in either pixel
    convention: OpenCV's centre is ((w - 1) / 2, (h - 1) / 2), COLMAP's (w / 2, h / 2))."""
    cx, cy = principal_point_px(intrinsics)
    return cx - (intrinsics.width - 1) / 2.0, cy - (intrinsics.height - 1) / 2.0


def focal_text(intrinsics: CameraIntrinsics) -> str:
    """The focal length (px): one number, or fx/fy where they differ (OPENCV, OPENCV_FISHEYE,
    PINHOLE models fit them apart)."""
    names = intrinsics.parameter_names
    if "fx" in names and "fy" in names:
        fx, fy = (float(intrinsics.params[names.index(k)]) for k in ("fx", "fy"))
        if abs(fx - fy) >= 0.05:
            return f"{fx:.1f}/{fy:.1f}"
    return f"{mean_focal_px(intrinsics):.1f}"


def short_names(names: Sequence[str], width: int) -> dict[str, str]:
    """Each name as at most `width` characters: a longer one keeps its head and its tail (where
    rigs number their cameras: "cam_07", best whole, from a separator) around SHORTENED, the
    split moved until no two names read alike."""
    out = {}
    for name in names:
        out[name] = name
        if len(name) <= width:
            continue
        taken = set(out.values()) | {n for n in names if len(n) <= width}
        lo, hi = max(1, (width - 1) // 4), (width - 1) // 2  # the tail's share: 1/4 to 1/2
        whole = [t for t in range(hi, lo - 1, -1) if not name[-t - 1].isalnum()]
        for tail in whole + list(range(lo, width - 1)):
            short = name[:width - 1 - tail] + SHORTENED + name[len(name) - tail:]
            if short not in taken:
                out[name] = short
                break
        else:  # alike at every split: a number tells them apart
            number = str(list(names).index(name))
            out[name] = name[:width - 1 - len(number)] + SHORTENED + number
    return out


def table_names(rig: RigCalibration) -> dict[str, str]:
    """Camera name -> as the report's tables print it: whole where the intrinsics' columns leave
    room within TABLE_COLUMNS (at most NAME_COLUMNS[1]), else shortened (short_names)."""
    cams = rig.cameras.values()
    # the columns after the name (camera_table): model, size, focal, then f_std cx cy pp_std
    # pp_from proj_std, and the space before each
    rest = (max([5] + [len(c.intrinsics.model) for c in cams])
            + max([4] + [len(f"{c.intrinsics.width}x{c.intrinsics.height}") for c in cams])
            + max([8] + [len(focal_text(c.intrinsics)) for c in cams]) + 40 + 9)
    width = min(max([NAME_COLUMNS[0]] + [len(n) for n in rig.cameras]),
                max(NAME_COLUMNS[0], min(NAME_COLUMNS[1], TABLE_COLUMNS - rest)))
    return short_names(list(rig.cameras), width)


def shortened_line(short: dict[str, str]) -> list[str]:
    """The lines that give the full names of those `short` shortened: one, when every one lost
    the same middle; [] when none was."""
    renamed = {n: s for n, s in short.items() if s != n}
    if not renamed:
        return []
    middles = set()
    for name, text in renamed.items():
        head, _, tail = text.partition(SHORTENED)
        middles.add(name[len(head):len(name) - len(tail)])
    if len(middles) == 1 and all(SHORTENED not in n for n in renamed):
        return _wrapped(f"names shortened: {SHORTENED} stands for {middles.pop()!r}")
    return _wrapped("names shortened: " + ", ".join(f"{s} = {n}" for n, s in renamed.items()))


def camera_table(rig: RigCalibration) -> str:
    """Two blocks, TABLE_COLUMNS wide at most. Intrinsics per camera: model, image size, focal
    (fx/fy where they differ) and its standard deviation, principal point (px, OpenCV
    convention as in the written files) and its standard deviation, how it was decided (pp_from:
    PrincipalPoint) and the standard deviation of where a ray projects (proj_std: the
    intrinsics as a whole). Fit per camera: reprojection RMS, observations (all / seen by >= 3
    cameras), the fraction of the image covered by observations, and the distortion
    (wrapped under its column). Standard deviations: core.method.uncertainty ('-' where not
    estimated, 'given' for intrinsics the user gave and the calibration kept). Names as
    table_names prints them, the shortened ones' full names below."""
    given = set(rig.quality.given_intrinsics or ())
    cams = rig.cameras
    short = table_names(rig)
    sizes = {n: f"{c.intrinsics.width}x{c.intrinsics.height}" for n, c in cams.items()}
    focal = {n: focal_text(c.intrinsics) for n, c in cams.items()}
    name_w = max([len("camera")] + [len(s) for s in short.values()])
    model_w = max([5] + [len(c.intrinsics.model) for c in cams.values()])
    size_w = max([4] + [len(s) for s in sizes.values()])
    focal_w = max([8] + [len(f) for f in focal.values()])
    lines = ["intrinsics, px (cx, cy: OpenCV pixels, the image centre at ((w-1)/2, (h-1)/2); "
             "COLMAP's are +0.5)",
             f"{'camera':<{name_w}} {'model':<{model_w}} {'size':>{size_w}} "
             f"{'focal_px':>{focal_w}} {'f_std':>5} {'cx':>7} {'cy':>7} {'pp_std':>6} "
             f"{'pp_from':>7} {'proj_std':>8}"]
    for name, cam in cams.items():
        cx, cy = principal_point_px(cam.intrinsics)
        q = cam.quality
        stds = ["given"] * 3 if name in given else ["-"] * 3 if q is None else [
            _optional(q.focal_std_px, ".1f"), _optional(q.principal_point_std_px, ".1f"),
            _optional(q.projection_std_px, ".2f")]
        lines.append(f"{short[name]:<{name_w}} {cam.intrinsics.model:<{model_w}} "
                     f"{sizes[name]:>{size_w}} {focal[name]:>{focal_w}} {stds[0]:>5} {cx:7.1f} "
                     f"{cy:7.1f} {stds[1]:>6} {principal_point_case(rig, name).value:>7} "
                     f"{stds[2]:>8}")
    lines += ["", "fit and distortion",
              f"{'camera':<{name_w}} {'rms_px':>6} {'obs':>6} {'obs3+':>6} {'coverage':>8}  "
              "distortion"]
    indent = name_w + 32  # where the distortion starts: after the name and the fit's columns
    for name, cam in cams.items():
        q = cam.quality
        fit = (f"{'-':>6} {'-':>6} {'-':>6} {'-':>8}" if q is None else
               f"{q.reprojection_rms_px:6.2f} {q.num_observations:6d} "
               f"{_optional(q.num_multiview_observations, 'd'):>6} {q.coverage:8.2f}")
        wrapped = textwrap.wrap(distortion_text(cam.intrinsics),
                                max(20, TABLE_COLUMNS - indent)) or [""]
        lines.append(f"{short[name]:<{name_w}} {fit}  {wrapped[0]}".rstrip())
        lines += [" " * indent + more for more in wrapped[1:]]
    return "\n".join(lines + shortened_line(short))


def _wrapped(text: str) -> list[str]:
    """text as lines of at most TABLE_COLUMNS, the later ones indented."""
    return textwrap.wrap(text, TABLE_COLUMNS, subsequent_indent="  ", break_long_words=False,
                         break_on_hyphens=False)


def intrinsics_note(rig: RigCalibration) -> str:
    """Lines under the camera table (at most TABLE_COLUMNS wide), one per way the principal
    points were decided (principal_point_case), naming the cameras, with the offset from the
    image centre of those not estimated; which pixel aspects the images estimated; and, for
    calibrations that held principal points in a final bundle adjustment with a
    held_pp_std_fraction, that their f_std and proj_std include that offset; where the runs'
    spread widened them, that. '' where there is nothing to say."""
    cases: dict[PrincipalPoint, list[str]] = {}
    for name in rig.cameras:
        cases.setdefault(principal_point_case(rig, name), []).append(name)
    if set(cases) <= {PrincipalPoint.UNKNOWN}:
        return ""
    short = table_names(rig)

    def offsets(names):
        return ", ".join(f"{short[n]} ({_offset_text(rig.cameras[n].intrinsics)})"
                         for n in names)

    fraction = rig.quality.principal_point_prior_std_fraction
    recalibration = rig.quality.change_summary is not None
    prior = (f"{100 * fraction:g} % of the long side around the image centre" if fraction
             else "around the image centre") + (
        " or a previous calibration's estimate" if recalibration else "")
    wording = {
        PrincipalPoint.ESTIMATED: "principal point estimated from the images: {}",
        PrincipalPoint.PRIOR: f"principal point resting on its prior ({prior}): the images do not "
                              "pin it down, so it was placed between their estimate and the "
                              "prior's centre, weighed by their spreads, and held there (pp_std: "
                              "how far a real camera's may lie from there): {}",
        PrincipalPoint.CENTRE: "principal point held exactly at the image centre: {}",
        PrincipalPoint.HELD: "principal point held where the calibration started it: {}",
        PrincipalPoint.GIVEN: "principal point given (--intrinsics) and kept: {}",
        PrincipalPoint.UNKNOWN: "principal point: the file does not say how it was found: {}"}
    lines = []
    for case in (c for c in PrincipalPoint if c in cases):
        names = cases[case]
        listed = offsets(names) if case in (PrincipalPoint.PRIOR, PrincipalPoint.HELD,
                                             PrincipalPoint.UNKNOWN) \
            else ", ".join(short[n] for n in names)
        lines += _wrapped(wording[case].format(listed))
    for parameter, said in (("aspect", "pixel aspect estimated (fx/fy)"),
                            ("p1", "decentering distortion estimated (p1, p2: held-out "
                                   "correspondences asked for it)")):
        names = [short[n] for n, c in rig.cameras.items() if c.quality is not None
                 and isinstance(c.quality.estimated_intrinsics, list)
                 and parameter in c.quality.estimated_intrinsics]
        if names:
            lines += _wrapped(f"{said}: {', '.join(names)}")
    held_fraction = rig.quality.held_pp_std_fraction  # absent in files written before it
    held_names = [n for n in cases.get(PrincipalPoint.CENTRE, [])
                  + cases.get(PrincipalPoint.HELD, [])
                  if rig.cameras[n].quality.focal_std_px is not None] if held_fraction else []
    held = [short[n] for n in held_names]
    if held:
        # files written before 2026-12-06 have no pp_std for a held point
        own = all(rig.cameras[n].quality.principal_point_std_px is not None for n in held_names)
        said = ("pp_std of {} is where a real principal point may lie, and their f_std and "
                "proj_std include it" if own else
                "f_std and proj_std of {} include where a real principal point may lie")
        lines += _wrapped(f"{said.format(', '.join(held))}: {100 * held_fraction:g} % of the long "
                          "side "
                          "(1 sigma per axis; on a perspective video frame's short axis "
                          f"{100 * CROPPED_FRAME_PP_STD_FRACTION:g} % of that side) from where "
                          "the calibration held it")
    runs = rig.quality.sigmas_runs_spread
    if runs:
        lines += _wrapped(f"f_std, pp_std, proj_std and rot_std include how far the {runs} "
                          "calibration runs, which disagree, scatter: the images leave these "
                          "intrinsics open")
    other = rig.quality.sigmas_matchers_spread
    if other:
        lines += _wrapped("f_std, pp_std, proj_std and rot_std are widened where the "
                          f"calibration on {other}'s matches, not kept, stands further from this "
                          "one than both calibrations' sigmas allow")
    return "\n".join(lines)


def _offset_text(intrinsics: CameraIntrinsics) -> str:
    dx, dy = principal_point_offset_px(intrinsics)
    if abs(dx) < 0.05 and abs(dy) < 0.05:
        return "at the centre"
    return f"{dx:+.1f}, {dy:+.1f} px from the centre"


def _name_column(names: list[str], short: Optional[dict[str, str]]
                 ) -> tuple[int, dict[str, str]]:
    """(width, names as printed) of a camera column of the narrower tables: 16 wide as they
    always were; names as `short` gives them (the camera table's: table_names), else up to
    NAME_COLUMNS[1] wide."""
    short = {**short_names(names, NAME_COLUMNS[1]), **(short or {})}
    return max([16] + [len(short[n]) for n in names]), short


def _optional(value, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def camera_centres_in_rig(rig: RigCalibration) -> dict[str, np.ndarray]:
    """Each camera's optical centre in the rig frame (the reference camera's optical frame)."""
    return {n: -c.cam_from_rig[:3, :3].T @ c.cam_from_rig[:3, 3] for n, c in rig.cameras.items()}


def layout_table(rig: RigCalibration, short: Optional[dict[str, str]] = None) -> str:
    """Where each camera is in the rig frame (x right, y down, z forward of the reference camera):
    optical centre, its distance from the reference, the angle between its optical axis and
    the reference's, and the sigma of its rotation relative to the reference (deg; "-" where
    not estimated). Units are metres when the scale came from a known baseline, else the
    reconstruction's arbitrary unit."""
    unit = "m" if rig.metric_scale else "units"
    width, short = _name_column(list(rig.cameras), short)
    rows = [f"{'camera':<{width}} {f'x_{unit}':>9} {f'y_{unit}':>9} {f'z_{unit}':>9} "
            f"{f'dist_{unit}':>10} {'axis_deg':>8} {'rot_std':>7}"]
    for name, centre in camera_centres_in_rig(rig).items():
        centre = np.round(centre, 3) + 0.0  # no "-0.000"
        axis_in_rig = rig.cameras[name].cam_from_rig[:3, :3].T @ np.array([0.0, 0.0, 1.0])
        axis_deg = float(np.degrees(np.arccos(np.clip(axis_in_rig[2], -1.0, 1.0))))
        quality = rig.cameras[name].quality
        rot_std = _optional(None if quality is None else quality.rotation_std_deg, ".3f")
        rows.append(f"{short[name]:<{width}} {centre[0]:9.3f} {centre[1]:9.3f} "
                    f"{centre[2]:9.3f} {np.linalg.norm(centre):10.3f} {axis_deg:8.2f} "
                    f"{rot_std:>7}")
    return "\n".join(rows)


def change_table(change: dict[str, CameraChange],
                 short: Optional[dict[str, str]] = None) -> str:
    """Per camera in both calibrations: focal change (%), the median over its camera pairs of the
    relative rotation and translation-direction changes (deg), and the mean projection change
    (px) of its intrinsics."""
    width, short = _name_column(list(change), short)
    rows = [f"{'camera':<{width}} {'focal_%':>8} {'rot_deg':>8} {'dir_deg':>8} {'proj_px':>8}"]
    for name, c in change.items():
        proj = "-" if c.projection_change_px is None else f"{c.projection_change_px:.2f}"
        rows.append(f"{short[name]:<{width}} {c.focal_change_pct:+8.2f} "
                    f"{c.rotation_change_deg:8.3f} {c.translation_dir_change_deg:8.3f} "
                    f"{proj:>8}")
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
    for unit in q.identical_units or ():
        lines.append(f"identical units {', '.join(unit['cameras'])} (one set of intrinsics in the "
                     f"SfM): {unit['why']}")
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
    short = table_names(rig)  # the camera table's names in every table
    parts = ["\n".join(overall_lines(rig)), "", camera_table(rig) + (f"\n{note}" if note else ""),
             "",
             "camera layout in the rig frame (reference camera's optical frame: x right, y down, "
             "z forward)", layout_table(rig, short)]
    if against is not None:
        parts += ["", f"change from {against_label}",
                  change_table(calibration_change(against, rig), short)]
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
