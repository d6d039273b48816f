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


def test_pycolmap_imported_first_is_refused_with_the_fix(tmp_path):
    """pycolmap before cv2 binds pycolmap's zlib: the first PNG written aborts the process (a
    lost notebook kernel). The package warns at import with the fix, and its PNG writers raise
    InputError instead of aborting; in the right order PNGs are written."""
    wrong = subprocess.run([sys.executable, "-c", (
        "import pycolmap, densecalib_ros\n"
        "from densecalib_ros.core.errors import InputError\n"
        "from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig\n"
        "rig = generate_rig(RigSpec(lenses='ideal', num_cameras=3, width=64, height=48, seed=1))\n"
        "try:\n    write_rig(rig, 'never')\nexcept InputError as e:\n    print('refused', e)\n")],
        capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert wrong.returncode == 0, wrong.stderr[-2000:]
    assert "RuntimeWarning" in wrong.stderr and "before pycolmap" in wrong.stderr
    assert wrong.stdout.startswith("refused pycolmap was imported before densecalib_ros")
    assert not (tmp_path / "never").exists()
    right = subprocess.run([sys.executable, "-c", "import densecalib_ros, pycolmap, cv2, numpy; "
                            "print(len(cv2.imencode('.png', numpy.zeros((8, 8), 'uint8'))[1]))"],
                           capture_output=True, text=True, timeout=120)
    assert right.returncode == 0 and int(right.stdout) > 0, right.stderr
