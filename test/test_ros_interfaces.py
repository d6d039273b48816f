"""The repository's ROS interface packages agree with what builds them: each ament_cmake package's
package.xml, CMakeLists.txt and interface files name the same package, files and dependencies (as
colcon and rosidl read them on a ROS install); densecalib_ros depends on the one it serves; and
scripts/build_interfaces.sh builds each of them into the PyPI environment. No ROS needed."""
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BUILD_SCRIPT = ROOT / "scripts" / "build_interfaces.sh"
# name -> its folder: the package colcon builds beside densecalib_ros, and the tf2_msgs stand-in
# that only the PyPI environment builds
PACKAGES = {"densecalib_interfaces": ROOT / "interfaces" / "densecalib_interfaces",
            "tf2_msgs": ROOT / "scripts" / "tf2_msgs_pkg"}


def cmake_interfaces(folder: Path) -> tuple[str, list[str], list[str]]:
    """(project name, interface files, DEPENDENCIES) of a package's CMakeLists.txt."""
    text = (folder / "CMakeLists.txt").read_text()
    project = re.search(r"^project\((\w+)\)", text, re.M).group(1)
    call = re.search(r"rosidl_generate_interfaces\(\$\{PROJECT_NAME\}(.*?)\)", text, re.S).group(1)
    files = re.findall(r'"([^"]+)"', call.split("DEPENDENCIES")[0])
    depends = call.split("DEPENDENCIES")[1].split() if "DEPENDENCIES" in call else []
    return project, files, depends


@pytest.mark.parametrize("name", sorted(PACKAGES))
def test_an_interface_package_names_its_files_and_dependencies_once(name):
    folder = PACKAGES[name]
    manifest = ET.parse(folder / "package.xml").getroot()
    assert manifest.findtext("name") == name
    project, files, depends = cmake_interfaces(folder)
    assert project == name
    on_disk = sorted(str(p.relative_to(folder)) for kind in ("msg", "srv", "action")
                     for p in (folder / kind).glob(f"*.{kind}"))
    assert sorted(files) == on_disk, (files, on_disk)
    assert manifest.findtext("export/build_type") == "ament_cmake"
    assert manifest.findtext("member_of_group") == "rosidl_interface_packages"
    tools = {d.text for d in manifest.findall("buildtool_depend")}
    assert {"ament_cmake", "rosidl_default_generators"} <= tools
    declared = {d.text for d in manifest.findall("depend")}
    assert set(depends) <= declared, (depends, declared)
    assert "rosidl_default_runtime" in {d.text for d in manifest.findall("exec_depend")}
    # an action needs action_msgs (its goal ids and status); a field naming another package's type
    # needs that package
    if any(f.endswith(".action") for f in files):
        assert "action_msgs" in declared
    for path in files:
        for field_type in re.findall(r"^\s*(\w+)/\w+", (folder / path).read_text(), re.M):
            assert field_type in declared, (path, field_type)


def test_densecalib_ros_depends_on_the_interfaces_it_serves_and_setup_builds_them():
    manifest = ET.parse(ROOT / "package.xml").getroot()
    assert "densecalib_interfaces" in {d.text for d in manifest.findall("exec_depend")}
    script = BUILD_SCRIPT.read_text()
    for name, folder in PACKAGES.items():
        entry = re.search(rf'^\s*"{name}\|\$repo/([^|]+)\|([^"]+)"', script, re.M)
        assert entry, f"{name} is not in {BUILD_SCRIPT.name}'s packages"
        assert ROOT / entry.group(1) == folder
        assert f"from {name}." in entry.group(2)  # the import that proves it is there
    assert 'bash "$repo/scripts/build_interfaces.sh" "$venv"' in \
        (ROOT / "scripts" / "setup_env.sh").read_text()
    # the node serves the action type of the package, by its generated module
    node_sources = "".join(p.read_text() for p in (ROOT / "densecalib_ros" / "ros").glob("*.py"))
    assert "from densecalib_interfaces.action import Calibrate" in node_sources
