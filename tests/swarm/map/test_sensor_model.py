"""The sensor model of docs/design.md section 3 at hand-computed points."""

import math

import numpy as np
import pytest

from swarm.map.sensor_model import SensorModel

E = 0.1
S = SensorModel(sigma_min=0.06, zeta=0.0375, tau=2.0, max_range=5.0)


@pytest.mark.parametrize(
    "d,d_l,mu",
    [
        (2.0, 1.0, 0.0),  # well before the hit: free
        (2.0, 1.95, 0.0),  # exactly e/2 before: still free (d_l <= d - e/2)
        (2.0, 1.97, 0.2),  # inside the hit voxel: 1/2 + (1.97 - 2)/0.1
        (2.0, 2.0, 0.5),
        (2.0, 2.04, 0.9),
        (2.0, 2.05, 1.0),  # e/2 behind: covered
        (2.0, 2.3, 1.0),
    ],
)
def test_mean_at_hand_computed_points(d, d_l, mu):
    assert S.mean(d, d_l, E) == pytest.approx(mu, abs=1e-9)


def test_sigma_at_hand_computed_points():
    sigma_s = 0.06 + 0.0375 * 3.0  # 0.1725 at 3 m
    assert S.sigma_s(3.0) == pytest.approx(sigma_s)
    assert S.sigma(3.0, 3.03, E) == pytest.approx(sigma_s)  # within e/2: sigma_s
    assert S.sigma(3.0, 2.95, E) == pytest.approx(sigma_s)  # exactly e/2 away: sigma_s
    # 1.05 m before the hit: decays by exp(-(1.05 - 0.05) / 2)
    assert S.sigma(3.0, 1.95, E) == pytest.approx(sigma_s * math.exp(-0.5))
    assert S.sigma(3.0, 3.45, E) == pytest.approx(sigma_s * math.exp(-0.2))


def test_prior_is_ten_times_sensor_sigma_at_max_range():
    assert S.prior_sigma() == pytest.approx(10 * (0.06 + 0.0375 * 5.0))


@pytest.mark.parametrize(
    "field,value", [("sigma_min", -0.06), ("tau", 0.0), ("max_range", np.nan), ("zeta", -1)]
)
def test_invalid_parameters_are_rejected_with_their_name(field, value):
    with pytest.raises(ValueError, match=field):
        SensorModel(**{field: value})
