"""The ROS package's files agree with each other: the launch file starts the node that setup.py
installs, with a parameters file that setup.py installs, and names only launch arguments it
declares. (`ros2 launch` is not available here to run it: see docs/ros.md.)"""
import re
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
LAUNCH = ROOT / "launch" / "densecalib.launch.xml"


def _installed_files() -> dict[str, str]:
    """Repository path -> install path (under the prefix) of setup.py's data_files globs."""
    text = (ROOT / "setup.py").read_text()
    package = re.search(r'package_name = "([^"]+)"', text).group(1)
    installed = {}
    globs = re.findall(r'\("share/" \+ package_name \+ "(/[^"]*)", glob\("([^"]+)"\)', text)
    for folder, pattern in globs:
        for path in ROOT.glob(pattern):
            installed[str(path.relative_to(ROOT))] = f"share/{package}{folder}/{path.name}"
    return installed


def test_launch_file_starts_the_installed_node_with_an_installed_parameters_file():
    package = ET.parse(ROOT / "package.xml").getroot().findtext("name")
    setup = (ROOT / "setup.py").read_text()
    launch = ET.parse(LAUNCH).getroot()
    assert launch.tag == "launch"
    args = {a.get("name"): a.get("default") for a in launch.findall("arg")}
    nodes = launch.findall("node")
    assert len(nodes) == 1
    node = nodes[0]
    assert node.get("pkg") == package
    assert re.search(rf'"{node.get("exec")} = densecalib_ros\.ros\.main:main"', setup)
    used = set(re.findall(r"\$\(var (\w+)\)", LAUNCH.read_text()))
    assert used <= set(args), used - set(args)
    # the default parameters file is the package's own, and installed where find-pkg-share looks
    (params,) = [p.get("from") for p in node.findall("param")]
    assert params == "$(var params_file)"
    default = args["params_file"]
    prefix = f"$(find-pkg-share {package})/"
    assert default.startswith(prefix)
    installed = _installed_files()
    source = default[len(prefix):]
    assert (ROOT / source).is_file() and installed[source] == f"share/{package}/{source}"
    assert installed[str(LAUNCH.relative_to(ROOT))] == f"share/{package}/launch/{LAUNCH.name}"
    depends = {d.text for d in ET.parse(ROOT / "package.xml").getroot().findall("exec_depend")}
    assert {"launch_ros", "launch_xml"} <= depends
