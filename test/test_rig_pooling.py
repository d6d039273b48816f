"""core.method.rig_pooling: the rig's own spread of an intrinsic (DerSimonian-Laird); the tie
itself in the adjustment: test_prior_adjustment."""
import numpy as np

from densecalib_ros.core.method.rig_pooling import (MIN_SPREAD_CAMERAS, SHARED_FRACTION,
                                                    random_effects, spread_ties)


def test_cameras_of_one_model_share_the_value():
    """Estimates that scatter only as far as their own errors: no spread between the cameras,
    the mean weighted by precision, and a tie tight enough to hold the cameras together."""
    rng = np.random.default_rng(0)
    stds = np.array([0.5, 1.0, 2.0, 1.0, 0.7, 1.5])
    values = 500.0 + 0.3 * stds * rng.standard_normal(len(stds))  # tighter than their errors
    effects = random_effects(values, stds)
    assert effects.spread == 0.0
    w = 1 / stds ** 2
    assert abs(effects.mean - np.sum(w * values) / np.sum(w)) < 1e-9
    assert abs(effects.mean_std - np.sqrt(1 / np.sum(w))) < 1e-12
    assert effects.sigma == SHARED_FRACTION * effects.mean_std


def test_different_lenses_keep_their_spread():
    """Cameras 20 px apart with 1 px errors: the spread between them is measured as such, and
    each camera's tie is about as wide (it barely moves an estimate)."""
    rng = np.random.default_rng(1)
    truth = 500.0 + 20.0 * rng.standard_normal(40)
    stds = np.full(40, 1.0)
    effects = random_effects(truth + rng.standard_normal(40), stds)
    assert 15.0 < effects.spread < 25.0
    assert effects.sigma == effects.spread
    assert abs(effects.mean - np.mean(truth)) < 3 * effects.mean_std


def test_a_few_cameras_share_no_value_their_scatter_cannot_tell():
    """Four estimates that scatter within their errors give a spread of 0, which from so few
    cameras is as likely lenses that differ: that intrinsic is left untied, the others tied at
    their spread; from MIN_SPREAD_CAMERAS on, a spread of 0 shares the value."""
    rng = np.random.default_rng(2)
    stds = np.full(6, 1.0)
    within = random_effects(500.0 + 0.3 * rng.standard_normal(4), stds[:4])
    apart = random_effects(np.array([400.0, 450.0, 520.0, 610.0]), stds[:4])
    assert within.spread == 0.0 and apart.spread > 50.0
    ties, untied = spread_ties({0: within, 3: apart}, [0, 1, 2, 3], 4)
    assert untied == [0] and [i for i, _ in ties] == [3]
    assert ties[0][1] == {b: apart.sigma for b in range(4)}
    many = random_effects(500.0 + 0.3 * rng.standard_normal(MIN_SPREAD_CAMERAS),
                          stds[:MIN_SPREAD_CAMERAS])
    ties, untied = spread_ties({0: many}, list(range(MIN_SPREAD_CAMERAS)), MIN_SPREAD_CAMERAS)
    assert many.spread == 0.0 and not untied and ties[0][1][0] == SHARED_FRACTION * many.mean_std
