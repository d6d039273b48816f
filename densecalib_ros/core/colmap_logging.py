"""How much of COLMAP's own logging (glog, shared with Ceres inside pycolmap) reaches the console.
densecalib reports progress and problems in its own words; COLMAP's and Ceres's warnings (a
"Linear solver failure" inside a bundle adjustment that then recovers) mean nothing to a user
and are kept for --verbose."""
from __future__ import annotations

import contextlib
from typing import Iterator

GLOG_ERROR = 2
GLOG_FATAL = 3


def show_colmap_log(verbose: bool) -> None:
    """Process-wide: every COLMAP/Ceres message when `verbose`, else errors only."""
    import pycolmap

    pycolmap.logging.minloglevel = 0 if verbose else GLOG_ERROR


@contextlib.contextmanager
def quiet_colmap(min_level: int = GLOG_FATAL) -> Iterator[None]:
    """Only COLMAP (glog) messages at `min_level` or above (2 = ERROR, 3 = FATAL) while inside;
    restored after. The default keeps only fatal ones: a peer's failure reaches the caller as
    PeerResult.message instead."""
    import pycolmap

    previous = pycolmap.logging.minloglevel
    pycolmap.logging.minloglevel = min_level
    try:
        yield
    finally:
        pycolmap.logging.minloglevel = previous
