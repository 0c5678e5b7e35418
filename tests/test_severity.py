"""Vibration severity on signals whose answer is known."""
import math

import numpy as np
import pytest
from scipy import signal as ssig

from millvib_env import MillParams, PIDGains
from millvib_env.plant.integrate import simulate
from millvib_env.severity import iso_table, iso_zone, vibration_severity

FS = 10_000.0
T = np.arange(int(2.0 * FS)) / FS


def tone_velocity(f_hz, v_amp):
    return v_amp * np.sin(2 * np.pi * f_hz * T)


@pytest.mark.parametrize("f_hz", [20.0, 115.5, 400.0, 900.0])
def test_in_band_tone_gives_its_rms_from_every_quantity(f_hz):
    v_amp = 5e-3  # m/s -> 3.536 mm/s RMS
    w = 2 * np.pi * f_hz
    vel = tone_velocity(f_hz, v_amp)
    acc = v_amp * w * np.cos(w * T)
    disp = -v_amp / w * np.cos(w * T)
    expected = 1000 * v_amp / math.sqrt(2)
    for signal, quantity in ((acc, "acceleration"), (vel, "velocity"), (disp, "displacement")):
        assert vibration_severity(signal, FS, quantity=quantity) == pytest.approx(expected, rel=0.01), quantity


@pytest.mark.parametrize("quantity", ["acceleration", "velocity", "displacement"])
def test_out_of_band_drift_and_hiss_are_removed(quantity):
    rng = np.random.default_rng(0)
    tone = tone_velocity(115.5, 2e-3)  # 1.41 mm/s RMS
    drift = 0.05 * np.sin(2 * np.pi * 0.7 * T) + 0.02 * T  # slow wander and a ramp: 25x the tone
    # hiss an octave above the band at half the tone's RMS, not periodic in the record
    sos = ssig.butter(8, (1500, 3000), btype="bandpass", fs=FS, output="sos")
    hiss = ssig.sosfilt(sos, rng.normal(0, 1e-3, T.size))

    def as_quantity(vel):
        if quantity == "acceleration":
            return np.gradient(vel, 1 / FS)
        if quantity == "displacement":
            return np.cumsum(vel) / FS
        return vel

    clean = vibration_severity(as_quantity(tone), FS, quantity=quantity)
    dirty = vibration_severity(as_quantity(tone + drift + hiss), FS, quantity=quantity)
    assert dirty == pytest.approx(clean, rel=0.02)
    assert vibration_severity(as_quantity(drift), FS, quantity=quantity) < 0.01 * clean
    # what hiss leaves in the band is bounded by the kink it makes at the record's ends
    assert vibration_severity(as_quantity(hiss), FS, quantity=quantity) < 0.15 * 1000 * hiss.std()


def test_acceleration_path_integrates_out_a_drifting_offset():
    # an accelerometer with a DC offset and a slow drift: plain time integration would explode
    acc = 9.81 + 0.5 * T + np.gradient(tone_velocity(300.0, 1e-3), 1 / FS)
    assert vibration_severity(acc, FS) == pytest.approx(1000 * 1e-3 / math.sqrt(2), rel=0.02)


@pytest.mark.parametrize("c1, ct, kp", [(2.25e6, 5e-9, 1e5), (1.25e5, 5e-16, 1e5), (2.25e6, 5e-16, 3.9e6),
                                       (1.25e5, 5e-16, 2e6)])
def test_acceleration_velocity_and_displacement_paths_agree_on_simulated_data(c1, ct, kp):
    # whole records: a 1 mm transient, the pump-driven response, or a limit cycle
    run = simulate(MillParams(c1=c1, Ct=ct), PIDGains(kp, 1e-3), 0.5)
    from_acc = run.severity(quantity="acceleration")
    assert run.severity(quantity="velocity") == pytest.approx(from_acc, rel=0.02)
    assert run.severity(quantity="displacement") == pytest.approx(from_acc, rel=0.02)


@pytest.mark.parametrize("bad, match", [
    (dict(signal=np.array([1.0, np.nan] * 8)), "NaN"),
    (dict(fs=-1.0), "fs"),
    (dict(band=(100.0, 10.0)), "band"),
    (dict(band=(10.0, 8000.0)), "Nyquist"),
    (dict(quantity="jerk"), "quantity"),
    (dict(signal=np.ones((4, 4))), "1-D"),
])
def test_bad_input_raises(bad, match):
    args = dict(signal=np.ones(64), fs=FS)
    args.update(bad)
    with pytest.raises(ValueError, match=match):
        vibration_severity(args.pop("signal"), args.pop("fs"), **args)


def test_iso_10816_3_zones():
    table = iso_table()
    assert table.boundaries_mm_s == (2.3, 4.5, 7.1) and "10816-3" in table.source
    assert [iso_zone(v) for v in (1.0, 2.3, 3.0, 5.0, 7.1, 20.0)] == ["A", "A", "B", "C", "C", "D"]
    assert iso_zone(3.0, "group1_flexible") == "A"
    with pytest.raises(ValueError, match="machine_class .* is invalid"):
        iso_zone(1.0, "group9")
    with pytest.raises(ValueError, match="severity"):
        iso_zone(float("nan"))


@pytest.mark.parametrize("edit, key", [
    ("boundaries_mm_s: [2.3, 4.5, 7.1]", "zones.group1_rigid.boundaries_mm_s"),
    ("band_hz: [10.0, 1000.0]", "band_hz"),
    ("default_class: group1_rigid", "default_class"),
])
def test_a_wrong_severity_config_value_is_refused_naming_its_key(tmp_path, monkeypatch, edit, key):
    import shutil

    from millvib_env import severity
    from millvib_env._paths import config_dir

    bad = {"boundaries_mm_s: [2.3, 4.5, 7.1]": "boundaries_mm_s: [4.5, .nan, 2.3]",
           "band_hz: [10.0, 1000.0]": "band_hz: [1000.0, 10.0]",
           "default_class: group1_rigid": "default_class: group9"}[edit]
    shutil.copytree(config_dir(), tmp_path / "configs")
    path = tmp_path / "configs" / "severity.yaml"
    path.write_text(path.read_text().replace(edit, bad, 1))
    monkeypatch.setenv("MILLVIB_CONFIGS", str(tmp_path / "configs"))
    severity._load_severity_config.cache_clear()
    try:
        with pytest.raises(ValueError, match=key.replace(".", r"\.")):
            severity.iso_zone(3.0)
    finally:
        monkeypatch.undo()
        severity._load_severity_config.cache_clear()


def test_the_severity_band_is_the_configs(tmp_path, monkeypatch):
    import shutil

    from millvib_env import severity
    from millvib_env._paths import config_dir

    fs, t = 10000.0, np.arange(0, 1.0, 1e-4)
    acc = 2 * np.pi * 500.0 * np.cos(2 * np.pi * 500.0 * t) * 1e-3  # a 500 Hz, 1 mm/s-amplitude velocity
    before = severity.vibration_severity(acc, fs)
    shutil.copytree(config_dir(), tmp_path / "configs")
    path = tmp_path / "configs" / "severity.yaml"
    path.write_text(path.read_text().replace("band_hz: [10.0, 1000.0]", "band_hz: [10.0, 400.0]", 1))
    monkeypatch.setenv("MILLVIB_CONFIGS", str(tmp_path / "configs"))
    severity._load_severity_config.cache_clear()
    try:
        assert severity.severity_band() == (10.0, 400.0)
        assert before > 0.5 and severity.vibration_severity(acc, fs) < 0.1 * before  # 500 Hz lies outside the band
    finally:
        monkeypatch.undo()
        severity._load_severity_config.cache_clear()


@pytest.mark.parametrize("quantity", ["acceleration", "velocity", "displacement"])
def test_rows_of_records_give_each_records_own_figures(quantity):
    from millvib_env.severity import band_levels, band_levels_rows, vibration_severity_rows

    rng = np.random.default_rng(3)
    records = np.cumsum(rng.normal(size=(5, 3001)), axis=1) * 1e-3
    lines = np.array([115.5, 115.5, 100.0, 115.5, 60.0])
    sev = vibration_severity_rows(records, FS, quantity=quantity, workers=2)
    levels = band_levels_rows(records, FS, quantity=quantity, line_hz=lines, workers=2)
    for j, rec in enumerate(records):
        assert sev[j] == pytest.approx(vibration_severity(rec, FS, quantity=quantity), rel=1e-12)
        single = band_levels(rec, FS, quantity=quantity, line_hz=lines[j])
        for key, value in single.items():
            assert levels[key][j] == pytest.approx(value, rel=1e-12), key
    with pytest.raises(ValueError, match="workers"):
        vibration_severity_rows(records, FS, workers=0)
    with pytest.raises(ValueError, match="2-D"):
        vibration_severity_rows(records[0], FS)


@pytest.mark.parametrize("n", [10001, 9001, 1000, 3])
@pytest.mark.parametrize("quantity", ["acceleration", "velocity", "displacement"])
def test_the_spectrum_from_a_dct_is_the_fft_of_the_mirror_extension(n, quantity):
    """The severity's spectra come from the records' n-point DCT-II or DST-II (`severity._extension_bins`), which
    equals the real FFT of the 2n-sample mirror extension (the definition, module docstring) in exact
    arithmetic. Measured: within 6e-16 of the largest bin at the environments' lengths (10,001 and 9,001); held to
    1e-12 (a wrong twiddle, sign or index is off by the bins' own size). Every bin, DC and Nyquist included, and
    the public spectrum over a band up to the Nyquist frequency."""
    from scipy import fft as sfft

    from millvib_env import severity

    rng = np.random.default_rng(n)
    x = np.cumsum(rng.normal(size=(4, n)), axis=1) * 1e-3
    fs = 10_000.0
    y = severity._detrended(x, fs, quantity)
    want = sfft.rfft(np.concatenate([y, -y[:, ::-1] if quantity == "velocity" else y[:, ::-1]], axis=1), axis=1)
    got = severity._extension_bins(y, quantity == "velocity", np.arange(n + 1), workers=2)
    assert np.max(np.abs(got - want)) <= 1e-12 * np.max(np.abs(want))
    if n >= 1000:
        band = (10.0, fs / 2)
        freqs, vel = severity.band_velocity_spectrum(x[0], fs, quantity=quantity, band=band)
        assert np.array_equal(freqs, sfft.rfftfreq(2 * n, 1.0 / fs))
        inside = (freqs >= band[0]) & (freqs <= band[1])
        assert not vel[~inside].any()
        jw = (2j * np.pi * freqs[inside]) ** {"acceleration": -1, "velocity": 0, "displacement": 1}[quantity]
        assert np.max(np.abs(vel[inside] / jw - want[0, inside])) <= 1e-12 * np.max(np.abs(want[0]))
