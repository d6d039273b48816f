"""Reading and writing: images, video, bags, time alignment of recordings, calibration folders
(calibration.json, the COLMAP model, reference views), the calibration store."""
