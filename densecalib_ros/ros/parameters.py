"""The node's ROS parameters: declared from ros.settings.PARAMETERS (descriptions, ranges, which
are read-only) and read back as the values parse_settings validates."""
from __future__ import annotations

from typing import Any, Optional

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.parameter import Parameter

from .settings import PARAMETERS, is_list_parameter


def declare_parameters(node: Node) -> None:
    """Every parameter of PARAMETERS on `node`, with its description and range."""
    for name, (default, description, read_only, ranges) in PARAMETERS.items():
        if is_list_parameter(name):  # any array type, checked by parse_settings; [] if unset
            node.declare_parameter(name, [], ParameterDescriptor(
                description=description, read_only=read_only, dynamic_typing=True))
            continue
        node.declare_parameter(name, default, ParameterDescriptor(
            description=description, read_only=read_only, **ranges))


def parameter_values(node: Node, changes: Optional[list[Parameter]] = None) -> dict[str, Any]:
    """{name: value} of every parameter of PARAMETERS on `node`, with `changes` (being set, not
    yet accepted) applied."""
    values = {}
    for name in PARAMETERS:
        param = node.get_parameter_or(name, Parameter(name, Parameter.Type.NOT_SET, None))
        values[name] = param.value
    for p in changes or []:
        values[p.name] = p.value
    return values
