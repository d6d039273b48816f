"""The benchmark harness (`densecalib bench`): scenes with reference cameras (generated rigs, real
photographs), the peers (COLMAP, GLOMAP) run on the same images, and the tables. Not part of the
calibration library (densecalib_ros.core); it uses it as a user would."""
