"""The rigs users build (issue 81) as bench scenes: 3-4 cameras 45-140 deg apart around a plain
room that a person or an animal walks through, filmed over many frame sets; pinhole and fisheye
lenses, mixed or units of one model; mounted high (a motion-capture ring) or low (camera traps,
webcams on desks); with what photographs have that renders lack (blur, noise, JPEG).

Each scene is generated from its seed (core.synthetic: room "plain", a walker); every method gets
every frame set (COLMAP: a camera's frames as one COLMAP camera, eval/peers.py)."""
from __future__ import annotations

from .bench import SceneSpec

# The webcams' size (Caliscope's), and that of the issue's timing figure (4 cameras x 20 frame
# sets in 2 minutes on 2 cores).
FEW_RIG_SIZE = (1280, 720)
# Caliscope's board edges measure a Gaussian blur of sigma 0.3-0.5 px, Pose2Sim's 0.8 px (the
# steepest step across a black-white edge against its height).
FEW_RIG_BLUR_PX = 0.5
# The real rigs' videos carry fewer bytes a frame than a JPEG of quality 30 of the same frame
# (Caliscope 28 kB and Pose2Sim 4 kB against 63 and 76 kB), though inter-frame coding spends
# them better on a still scene: quality 50 stands between.
FEW_RIG_JPEG_QUALITY = 50
# Pose2Sim's ring of one long-lens model (36 deg across its portrait frames' width).
FEW_RIG_LONG_FOV_DEG = (30.0, 40.0)
# (cameras, model, lens mix, walker, mount, degrees between neighbours, frame sets, seed); seeds
# of their own, used nowhere else. The pinhole "mixed" rigs draw 56-83 deg lenses, the fisheye
# ones 150-190 deg; "identical" rigs are units of one model (core.synthetic.intrinsics).
FEW_RIGS = (
    (3, "RADIAL", "mixed", "person", "low", 60, 20, 811),  # webcams around a desk
    (4, "RADIAL", "identical", "person", "high", 90, 20, 812),  # a motion-capture ring
    (4, "RADIAL", "mixed", "animal", "low", 50, 20, 813),  # camera traps along a trail
    (3, "RADIAL", "identical", "person", "high", 140, 20, 814),  # far apart, one model
    (3, "OPENCV_FISHEYE", "identical", "person", "high", 120, 20, 815),
    (4, "OPENCV_FISHEYE", "mixed", "animal", "low", 80, 20, 816),
    (4, "RADIAL", "identical-long", "person", "high", 90, 20, 817),  # Pose2Sim's kind of ring
)
# A head of fisheye units facing out from the room's middle (core.synthetic.rig's "outward"
# layout: a 360-degree camera, a trap on a post), whose neighbours share only their images' rims:
# the held-out rig of four 220 deg lenses. (cameras, field of view deg, lens mix,
# walker, mount, frame sets, seed.)
FEW_OUTWARD_RIGS = (
    (4, 220.0, "identical", "person", "low", 20, 818),
)


def _users_rig(walker: str, mount: str, mix: str, sets: int) -> tuple:
    """SceneSpec.rig of a room as users build them: plain, walked through, finished as the
    webcams' frames are (FEW_RIG_BLUR_PX, FEW_RIG_JPEG_QUALITY)."""
    return (("room", "plain"), ("walker", walker), ("mount", mount), ("lens_mix", mix),
            ("num_time_steps", sets), ("blur_sigma_px", FEW_RIG_BLUR_PX),
            ("jpeg_quality", FEW_RIG_JPEG_QUALITY))


def few_scenes() -> list[SceneSpec]:
    """The generated rigs of FEW_RIGS and FEW_OUTWARD_RIGS at FEW_RIG_SIZE, finished with
    FEW_RIG_BLUR_PX and FEW_RIG_JPEG_QUALITY (sensor noise: RigSpec's default)."""
    width, height = FEW_RIG_SIZE
    scenes = []
    for n, model, mix, walker, mount, gap, sets, seed in FEW_RIGS:
        long_lens = mix == "identical-long"
        lens = "fisheye" if model == "OPENCV_FISHEYE" else "pinhole"
        name = (f"synthetic-{walker}-{lens}-{'long-' if long_lens else ''}"
                f"{mix.removesuffix('-long')}-{mount}-gap{gap}-{n}cam-{sets}sets-"
                f"{width}x{height}-s{seed}")
        scenes.append(SceneSpec(name, "synthetic", n, model, width, height, seed,
                                gap_deg=float(gap), max_arc_deg=360.0,
                                fov_range_deg=FEW_RIG_LONG_FOV_DEG if long_lens else None,
                                rig=_users_rig(walker, mount, mix.removesuffix("-long"), sets)))
    for n, fov, mix, walker, mount, sets, seed in FEW_OUTWARD_RIGS:
        name = (f"synthetic-{walker}-fisheye{fov:.0f}-{mix}-outward-{mount}-{n}cam-{sets}sets-"
                f"{width}x{height}-s{seed}")
        scenes.append(SceneSpec(name, "synthetic", n, "OPENCV_FISHEYE", width, height, seed,
                                gap_deg=360.0 / n, max_arc_deg=360.0, layout="outward",
                                rig=_users_rig(walker, mount, mix, sets) + (("fov_deg", fov),)))
    return scenes
