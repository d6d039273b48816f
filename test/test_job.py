"""The calibration job the command and the node share (core.job): a recalibration of a metric
calibration keeps its scale without the baseline being given again, the floor and the provenance
are recorded, and a recalibration that loses the floor says what finds it again."""
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.job import CalibrationRequest, run_job
from densecalib_ros.core.products.scale import camera_distance
from densecalib_ros.core.synthetic import RigSpec, generate_rig


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL",
                                width=640, height=480, num_time_steps=2, seed=1))


def _request(rig, **kwargs):
    config = make_config("regular", consensus_runs=1, sfm__num_threads=1)
    names = [f"cam{c}" for c in range(len(rig.images[0]))]
    return CalibrationRequest(rig.images, names, config, {"source": "test"}, **kwargs)


def test_a_recalibration_keeps_the_previous_metric_scale_and_says_the_floor_is_lost(rig):
    truth = rig.ground_truth()
    baseline_m = camera_distance(truth, "cam0", "cam2")  # the generator's units are metres
    first = run_job(_request(rig, known_baseline=("cam0", "cam2", baseline_m), floor="upright"))
    assert first.rig.metric_scale
    assert camera_distance(first.rig, "cam0", "cam2") == pytest.approx(baseline_m)
    assert first.rig.quality.input == {"source": "test"}
    assert first.rig.quality.floor is not None
    assert sorted(first.reference_views) == sorted(first.rig.cameras)

    again = run_job(_request(rig, previous=first.rig, floor_hint="ask for the floor again"))
    assert again.rig.quality.init is not None  # a recalibration, from the first calibration
    assert again.rig.metric_scale  # the previous calibration's baseline, not given again
    assert camera_distance(again.rig, "cam0", "cam2") == pytest.approx(baseline_m)
    (lost,) = [w for w in again.rig.quality.warnings if "floor" in w]
    assert lost.endswith("ask for the floor again")
