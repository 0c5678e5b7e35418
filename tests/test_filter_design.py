"""The Butterworth designs kept on disk (`envs.filter_design`): scipy's own bits, read back without scipy.signal."""
import numpy as np
import pytest
from scipy import signal

from millvib_env.envs import filter_design as fd

DESIGNS = [(2, (10.0, 1000.0), "bandpass", 10_000.0), (2, 10.0, "highpass", 10_000.0)]


@pytest.fixture
def fresh_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(fd, "_MEMO", {})
    return tmp_path


@pytest.mark.parametrize("order, wn, btype, fs", DESIGNS)
def test_a_design_is_scipys_bit_for_bit_made_once_then_read_back(fresh_cache, monkeypatch, order, wn, btype, fs):
    want = signal.butter(order, wn, btype=btype, fs=fs, output="sos")
    made = fd.butter_sos(order, wn, btype, fs)
    assert made.dtype == np.float64 and made.flags.c_contiguous and np.array_equal(made, want)
    made[:] = 0.0  # a caller's copy: the next call is untouched
    assert np.array_equal(fd.butter_sos(order, wn, btype, fs), want)
    assert len(list((fresh_cache / "filters").glob("butter-*.npy"))) == 1

    def no_scipy(key):
        raise AssertionError("designed again although the file is there")

    monkeypatch.setattr(fd, "_MEMO", {})  # a new process: only the file
    monkeypatch.setattr(fd, "_design", no_scipy)
    assert np.array_equal(fd.butter_sos(order, wn, btype, fs), want)


def test_a_damaged_file_is_designed_again_and_rewritten(fresh_cache, monkeypatch):
    order, wn, btype, fs = DESIGNS[0]
    want = fd.butter_sos(order, wn, btype, fs)
    (file,) = (fresh_cache / "filters").glob("butter-*.npy")
    for damage in (b"not an array", np.zeros((2, 5)), np.full((2, 6), np.nan)):
        if isinstance(damage, bytes):
            file.write_bytes(damage)
        else:
            np.save(file, damage)
        monkeypatch.setattr(fd, "_MEMO", {})
        assert np.array_equal(fd.butter_sos(order, wn, btype, fs), want)
        assert np.array_equal(np.load(file, allow_pickle=False), want)


def test_without_a_cache_folder_scipy_designs_it_in_each_process(tmp_path, monkeypatch):
    monkeypatch.delenv("NUMBA_CACHE_DIR", raising=False)
    monkeypatch.setattr(fd, "_MEMO", {})
    order, wn, btype, fs = DESIGNS[1]
    assert np.array_equal(fd.butter_sos(order, wn, btype, fs), signal.butter(order, wn, btype=btype, fs=fs,
                                                                             output="sos"))
    blocked = tmp_path / "read-only"
    blocked.write_text("a file where the folder would be")  # the folder cannot be made: designed, not kept
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(blocked))
    monkeypatch.setattr(fd, "_MEMO", {})
    assert np.array_equal(fd.butter_sos(order, wn, btype, fs), signal.butter(order, wn, btype=btype, fs=fs,
                                                                             output="sos"))


def test_the_files_name_holds_the_arguments_the_format_and_the_versions(fresh_cache, monkeypatch):
    import scipy

    key = (2, (10.0, 1000.0), "bandpass", 10_000.0)
    name = fd._file(key)
    assert name is not None and name.parent == fresh_cache / "filters"
    assert fd._file((2, (10.0, 1000.0), "bandpass", 20_000.0)) != name
    monkeypatch.setattr(fd, "FORMAT", fd.FORMAT + 1)
    assert fd._file(key) != name
    monkeypatch.setattr(fd, "FORMAT", fd.FORMAT - 1)
    monkeypatch.setattr(scipy, "__version__", "0.0.0")
    assert fd._file(key) != name
