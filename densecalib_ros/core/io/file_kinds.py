"""The files a rig's images and videos are read from, by extension (one place for both readers,
which each name the other's kind when it sits where theirs was expected)."""

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp")
# The containers OpenCV's FFmpeg reads a camera's recording from (by extension: a folder of
# videos also holds time stamps, notes, calibration files).
VIDEO_EXTENSIONS = (".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".mts",
                    ".ts", ".m2ts", ".wmv", ".asf", ".flv", ".f4v", ".3gp", ".ogv", ".mxf",
                    ".vob", ".y4m")
