"""The named failure scenarios: the fixed PIDs' outcomes, measured by simulation."""
import pytest

from millvib_env.envs.scenarios import SCENARIOS, measure_scenario

ZONES = "ABCD"


@pytest.fixture(scope="module")
def measured():
    return {name: measure_scenario(name) for name in SCENARIOS}


@pytest.mark.parametrize("name", list(SCENARIOS))
def test_scenario_outcome_under_its_fixed_pid(measured, name):
    sc, m = SCENARIOS[name], measured[name]
    assert not m["diverged"]
    assert m["sustained"] == (sc.expect_motion == "sustained"), m
    assert ZONES.index(m["iso_zone"]) >= ZONES.index(sc.expect_zone), m
    if sc.worse_than:
        assert m["severity_mm_s"] > measured[sc.worse_than]["severity_mm_s"], (m, measured[sc.worse_than])


def test_paper_pid_leaves_zone_b_when_the_seals_leak(measured):
    assert measured["high-leakage"]["iso_zone"] in "CD"
    # and it sags: the leak flow needs an open valve, which a P-dominant loop only gets from an offset
    assert abs(measured["high-leakage"]["final_offset_um"]) > 100


def test_commissioned_pid_breaks_into_a_limit_cycle_when_damping_falls(measured):
    assert measured["commissioned-low-damping"]["motion"] in ("quasi-periodic",) or \
        measured["commissioned-low-damping"]["motion"].startswith("period")
    assert measured["commissioned-low-damping"]["severity_mm_s"] > 10 * measured["high-gain"]["severity_mm_s"]
