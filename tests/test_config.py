"""tpnet_ref.config: the one normalisation, the one parameter list, the validated config."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from tpnet_ref.config import NORM_HI, NORM_LO, TPNetConfig, denormalize, normalize, param_shapes


def test_normalize_maps_the_particle_centre_range_to_unit_interval():
    np.testing.assert_allclose(normalize([NORM_LO, NORM_HI, (NORM_LO + NORM_HI) / 2]),
                               [0.0, 1.0, 0.5], atol=1e-15)


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-1e3, 1e3), min_size=1, max_size=20))
def test_denormalize_inverts_normalize(xs):
    x = np.asarray(xs)
    np.testing.assert_allclose(denormalize(normalize(x)), x, rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("dtype, out", [(np.float32, np.float32), (np.float64, np.float64),
                                        (np.int64, np.float64)])
def test_normalize_keeps_float_dtypes_and_promotes_integers(dtype, out):
    assert normalize(np.ones(3, dtype=dtype)).dtype == out
    assert denormalize(np.ones(3, dtype=dtype)).dtype == out


def test_custom_range():
    np.testing.assert_allclose(normalize(3.0, lo=1.0, hi=5.0), 0.5)
    np.testing.assert_allclose(denormalize(0.5, lo=1.0, hi=5.0), 3.0)


def test_param_shapes_is_in_forward_order_and_counts_the_released_network():
    shapes = param_shapes(TPNetConfig())
    names = list(shapes)
    assert names[0] == "mlp1.0.w" and names[-1] == "head.b"
    assert names.index("global.w") < names.index("lstm1.fwd.kernel") < names.index("ln3.beta")
    assert sum(int(np.prod(s)) for s in shapes.values()) == 7_101_756   # identity transforms
    trained = param_shapes(TPNetConfig(input_transform_trained=True, feature_transform_trained=True))
    assert list(trained)[0] == "input_tnet.mlp.0.w"
    assert trained["feature_tnet.out.w"] == (128, 64 * 64)
    assert sum(int(np.prod(s)) for s in trained.values()) > 8_000_000      # spec: about 8.1M


@pytest.mark.parametrize("kw, exc, msg", [
    ({"m": 0}, ValueError, "TPNetConfig.m"),
    ({"m": 2.5}, TypeError, "TPNetConfig.m"),
    ({"lstm_units": ()}, ValueError, "lstm_units"),
    ({"lstm_units": "512"}, TypeError, "lstm_units"),
    ({"lstm_activation": "gelu"}, ValueError, "lstm_activation"),
    ({"layer_norm_eps": 0.0}, ValueError, "layer_norm_eps"),
    ({"norm_lo": 5.0, "norm_hi": 1.0}, ValueError, "norm_lo < norm_hi"),
])
def test_bad_configs_are_refused_naming_the_field(kw, exc, msg):
    with pytest.raises(exc, match=msg):
        TPNetConfig(**kw)


def test_config_round_trips_through_a_dict_and_refuses_unknown_fields():
    c = TPNetConfig(m=5, lstm_activation="tanh")
    assert TPNetConfig.from_dict(c.to_dict()) == c
    with pytest.raises(ValueError, match="unknown TPNetConfig field"):
        TPNetConfig.from_dict({**c.to_dict(), "dropout": 0.1})
