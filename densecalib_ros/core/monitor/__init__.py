"""Is a calibration still right: the epipolar check per frame set, each camera against its
reference view, what changed between two calibrations."""
