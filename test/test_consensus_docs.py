"""How many agreeing consensus runs end the consensus is said alike everywhere a user reads it:
the running node's `consensus_runs` parameter description (it said 3), `densecalib calibrate
--help`, docs/cli.md and the node's config file, all as the code has it
(consensus.EARLY_STOP_RUNS, pipeline._consensus_runs) (issue 85 item d)."""
import os
import re
import signal
import subprocess
import sys

import pytest

from densecalib_ros.core.robust.consensus import EARLY_STOP_RUNS

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
STOPS = re.compile(r"stops\s+(?:after|at)\s+(\d+)")


def _stops(text: str) -> list[int]:
    return [int(n) for n in STOPS.findall(text)]


def _child(*command) -> subprocess.Popen:
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", ""),
           "ROS_DOMAIN_ID": str(30 + (os.getpid() + 47) % 70)}
    return subprocess.Popen([sys.executable, *command], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env)


def test_help_docs_and_config_say_the_runs_the_code_stops_at():
    helped = _child("-m", "densecalib_ros.cli", "calibrate", "--help")
    text = helped.communicate(timeout=60)[0]
    assert helped.returncode == 0, text
    docs = open(os.path.join(REPO, "docs", "cli.md"), encoding="utf-8").read()
    config = open(os.path.join(REPO, "config", "densecalib.yaml"), encoding="utf-8").read()
    consensus = docs[docs.index("**Consensus.**"):]
    for where, said in (("--help", text), ("docs/cli.md", consensus[:consensus.index("\n\n")]),
                        ("config", next(line for line in config.splitlines()
                                        if "consensus_runs:" in line))):
        assert _stops(said)[:1] == [EARLY_STOP_RUNS], (where, said)


def test_the_running_nodes_parameter_description_says_the_runs_the_code_stops_at(tmp_path):
    rclpy = pytest.importorskip("rclpy", reason="the node needs rclpy (ROS 2 Jazzy)")
    from rcl_interfaces.srv import DescribeParameters
    from rclpy.executors import SingleThreadedExecutor

    node = _child("-c", "import sys; from densecalib_ros.ros.main import main; sys.exit(main())",
                  "--ros-args", "-p", "image_topics:=['/cam0/image_raw','/cam1/image_raw']",
                  "-p", f"output_dir:={tmp_path / 'out'}")
    lines = []
    try:
        for line in node.stdout:
            lines.append(line)
            if "ready:" in line:
                break
        context = rclpy.Context()
        rclpy.init(context=context, domain_id=int(30 + (os.getpid() + 47) % 70))
        try:
            client_node = rclpy.create_node("consensus_docs_probe", context=context)
            client = client_node.create_client(DescribeParameters,
                                               "/densecalib_node/describe_parameters")
            assert client.wait_for_service(timeout_sec=20.0), "".join(lines)
            future = client.call_async(DescribeParameters.Request(names=["consensus_runs"]))
            executor = SingleThreadedExecutor(context=context)
            executor.add_node(client_node)
            executor.spin_until_future_complete(future, timeout_sec=20.0)
            description = future.result().descriptors[0].description
        finally:
            rclpy.shutdown(context=context)
    finally:
        node.send_signal(signal.SIGTERM)
        node.communicate(timeout=30)
    assert _stops(description) == [EARLY_STOP_RUNS], description
