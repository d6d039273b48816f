"""Test-wide set-up. Importing the package first loads cv2 before pycolmap (see
densecalib_ros/__init__.py: the other order makes cv2's PNG writer abort the process)."""
import densecalib_ros  # noqa: F401
import pytest


@pytest.fixture(scope="module")
def torch_one_thread():
    """torch on one thread for a module's tests (2 cores are shared by the whole suite)."""
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(previous)
