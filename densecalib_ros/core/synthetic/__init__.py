"""Synthetic rigs with exact ground truth for tests, the demo and benchmarks.

    from densecalib_ros.core.synthetic import RigSpec, generate_rig
    rig = generate_rig(RigSpec(num_cameras=6, camera_model="OPENCV_FISHEYE", width=640, height=480))
    rig.images[t][c]                     # (H, W, 3) uint8 RGB
    rig.ground_truth()                   # RigCalibration, rig frame = cam0
    rig.transfer(t, a, b, xy_a_px)       # ground-truth correspondences a -> b (occlusion-aware)
"""
from .rig import RigSpec, SyntheticRig, generate_rig, read_ground_truth, write_rig

__all__ = ["RigSpec", "SyntheticRig", "generate_rig", "read_ground_truth", "write_rig"]
