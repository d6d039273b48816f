"""The core must import on a machine without rclpy: import every core module in a subprocess in
which importing rclpy (or any ROS message package) raises."""
import pkgutil
import subprocess
import sys
from pathlib import Path

import densecalib_ros.core

BLOCKER = r"""
import sys, importlib.abc
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in {'rclpy', 'sensor_msgs', 'tf2_msgs', 'std_srvs', 'geometry_msgs'}:
            raise ImportError('blocked ROS import: ' + name)
sys.meta_path.insert(0, Block())
import importlib
for m in sys.argv[1:]:
    importlib.import_module(m)
print('ok', len(sys.argv) - 1)
"""


def _core_modules():
    root = Path(densecalib_ros.core.__file__).parent
    mods = ["densecalib_ros.core"]
    for info in pkgutil.walk_packages([str(root)], prefix="densecalib_ros.core."):
        mods.append(info.name)
    return mods


def test_core_imports_without_rclpy():
    mods = _core_modules()
    assert len(mods) >= 3
    out = subprocess.run([sys.executable, "-c", BLOCKER, *mods], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 0, out.stderr[-3000:]
    assert f"ok {len(mods)}" in out.stdout


def test_package_import_order_keeps_png_encoding_alive():
    """Importing densecalib_ros before pycolmap must keep cv2's PNG encoder working (a zlib clash
    between the wheels aborts the process when pycolmap is loaded first)."""
    code = ("import densecalib_ros, pycolmap, cv2, numpy as np\n"
            "ok, buf = cv2.imencode('.png', np.zeros((8, 8, 3), np.uint8))\n"
            "assert ok and cv2.imdecode(buf, cv2.IMREAD_COLOR).shape == (8, 8, 3)\nprint('png ok')\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "png ok" in out.stdout


def test_pycolmap_imported_first_is_refused_with_the_fix():
    """pycolmap before cv2 binds pycolmap's zlib: the first PNG written aborts the process (a
    lost notebook kernel). The package says so at import, where it can still be fixed."""
    wrong = subprocess.run([sys.executable, "-c", "import pycolmap, densecalib_ros"],
                           capture_output=True, text=True, timeout=120)
    assert wrong.returncode == 1 and "ImportError" in wrong.stderr
    assert "import densecalib_ros, or cv2, before pycolmap" in wrong.stderr
    right = subprocess.run([sys.executable, "-c", "import densecalib_ros, pycolmap, cv2, numpy; "
                            "print(len(cv2.imencode('.png', numpy.zeros((8, 8), 'uint8'))[1]))"],
                           capture_output=True, text=True, timeout=120)
    assert right.returncode == 0 and int(right.stdout) > 0, right.stderr
