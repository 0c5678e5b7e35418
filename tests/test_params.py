import math

import numpy as np
import pytest

from millvib_env import MillParams, PIDGains, load_preset
from millvib_env.params import PARAM_FIELDS, list_presets, parse_overrides

TABLE_1 = {"Ap": 0.19635, "Ab": 0.030159, "mt": 1200, "c1": 2.25e6, "k1": 2.5e9, "FL": 2e6, "Ct": 5e-16,
           "ps": 1.8e7, "pt": 0.0, "pb": 1e6, "beta_e": 7e8, "rho": 850, "Cd": 0.62, "W": 0.025,
           "Kp1": 0.0125, "Ksv": 0.01, "L1": 0.15, "L": 0.26, "sigma0": 4.4178e9, "sigma1": 1e5,
           "sigma2": 1e5, "fc": 16000, "fs": 22000, "vs": 0.1}


def test_defaults_are_table_1_and_the_paper_pulsation():
    p = MillParams()
    for name, value in TABLE_1.items():
        assert getattr(p, name) == pytest.approx(value, rel=0, abs=0), name
    assert p.pulse_amp == 0.12
    assert p.pulse_freq == pytest.approx(990 / 60 * 7)


def test_paper_preset_equals_defaults():
    assert "paper" in list_presets()
    assert load_preset("paper") == MillParams()


def test_every_field_documents_unit_meaning_and_range():
    rows = MillParams.describe()
    assert [r[0] for r in rows] == list(PARAM_FIELDS)
    for name, _default, unit, doc, rule in rows:
        assert unit and doc and rule, name


@pytest.mark.parametrize("name, value", [
    ("mt", 0.0), ("mt", -1.0), ("Ct", -1e-12), ("c1", float("nan")), ("k1", float("inf")),
    ("fs", 1000.0),  # below fc
    ("L", 0.1),  # below L1
    ("Cd", 1.5), ("ps", 0.0), ("pulse_amp", 1.0), ("vs", 0.0), ("beta_e", -7e8), ("dp_reg", 0.0),
])
def test_bad_parameter_names_field_and_value(name, value):
    with pytest.raises(ValueError) as err:
        MillParams().replace(**{name: value})
    msg = str(err.value)
    assert f"MillParams.{name}" in msg and (repr(value) in msg or str(value) in msg)


def test_non_numeric_parameter_is_rejected():
    with pytest.raises(ValueError, match="MillParams.c1"):
        MillParams(c1="lots")
    with pytest.raises(ValueError, match="unknown MillParams field"):
        MillParams().replace(damping=1.0)


def test_saturation_may_be_infinite_but_not_nan():
    assert math.isinf(MillParams().u_max)
    with pytest.raises(ValueError, match="u_max"):
        MillParams(u_max=float("nan"))


@pytest.mark.parametrize("kw", [{"kp": -1.0}, {"kp": float("nan")}, {"kp": 1.0, "ki": float("inf")},
                                {"kp": 1.0, "kd": -0.1}])
def test_bad_gains_raise(kw):
    with pytest.raises(ValueError, match="PIDGains"):
        PIDGains(**kw)


def test_overrides_parse_and_validate():
    assert parse_overrides(["c1=2.25e5", "Ct = 5e-9"]) == {"c1": 2.25e5, "Ct": 5e-9}
    with pytest.raises(ValueError, match="NAME=VALUE"):
        parse_overrides(["c1"])
    with pytest.raises(ValueError, match="not a number"):
        parse_overrides(["c1=abc"])


def test_to_array_round_trip():
    p = MillParams(c1=3e5)
    assert np.array_equal(p.to_array(), np.array([p.to_dict()[k] for k in PARAM_FIELDS]))
    assert MillParams.from_dict(p.to_dict()) == p


def test_a_rod_side_larger_than_the_bore_and_a_non_boolean_pid_switch_are_refused():
    from millvib_env.plant.integrate import simulate

    with pytest.raises(ValueError, match=r"MillParams.Ab = 1.0 .*< Ap"):
        MillParams(Ab=1.0)
    with pytest.raises(ValueError, match=r"MillParams.Ab .*< Ap"):
        MillParams(Ab=MillParams().Ap)
    for bad in ("false", 0, 1.0, None):
        with pytest.raises(ValueError, match="pid_on"):
            simulate(pid_on=bad, t_end=0.01)
