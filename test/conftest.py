"""Test-wide set-up. Importing the package first loads cv2 before pycolmap (see
densecalib_ros/__init__.py: the other order makes cv2's PNG writer abort the process)."""
import densecalib_ros  # noqa: F401
