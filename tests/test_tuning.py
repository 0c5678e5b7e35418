"""Tuning at scale: an Optuna study in shared storage, worked on by several processes."""
import subprocess
import sys

import pytest

optuna = pytest.importorskip("optuna")


def test_two_workers_share_one_study_through_a_journal_file(tmp_path):
    storage = f"journal:{tmp_path / 'study.log'}"
    code = ("from millvib_env.training.tuning import tune_optuna; "
            f"print(tune_optuna([10100, 10101], task='startup', storage={storage!r}, study_name='s', n_trials=2))")
    workers = [subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
               for _ in range(2)]
    for w in workers:
        out, err = w.communicate(timeout=300)
        assert w.returncode == 0, err[-2000:]
    from millvib_env.training.tuning import optuna_storage

    study = optuna.load_study(study_name="s", storage=optuna_storage(storage))
    assert len(study.trials) == 4 and study.best_value > 0


def test_a_bad_storage_is_refused():
    from millvib_env.training.tuning import optuna_storage

    with pytest.raises(ValueError, match="--storage"):
        optuna_storage("somewhere")
