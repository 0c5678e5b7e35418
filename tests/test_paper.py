"""The paper's three studies: directions computed, not hard-coded."""
import pytest

from millvib_env.analysis.paper import PAPER_STUDIES, claims, run_studies


@pytest.fixture(scope="module")
def studies():
    return run_studies(t_end=1.0)  # the reproduction's horizon


@pytest.mark.parametrize("key", ["c1", "Ct", "KP"])
def test_severity_rises_along_each_study(studies, key):
    results, _ = studies
    sev = [r.severity_mm_s for r in results if r.study == key]
    assert sev[0] < sev[1] < sev[2], sev


def test_claims_table_reports_the_directions(studies):
    results, _ = studies
    table = {c["study"]: c for c in claims(results)}
    assert all(table[k]["direction_reproduced"] for k in ("c1", "Ct", "KP"))


def test_leakage_makes_the_pump_ripple_visible(studies):
    # with leakage the valve stays open, so the supply ripple drives a 115.5 Hz response
    results, _ = studies
    leaky = [r for r in results if r.study == "Ct"][-1]
    # sustained at the pump frequency; "periodic" vs "quasi-periodic" is not asserted (it is a rounding-level call)
    assert leaky.motion not in ("decay", "diverged") and abs(leaky.frequency_hz - 115.5) < 3


def test_the_studies_match_the_paper_setup():
    assert [c.value for c in PAPER_STUDIES[0].cases] == [2.25e6, 2.25e5, 1.25e5]
    assert [c.value for c in PAPER_STUDIES[1].cases] == [5e-16, 5e-10, 5e-9]
    assert [c.gains.kp for c in PAPER_STUDIES[2].cases] == [1e5, 3.5e6, 3.9e6]


def test_ode45_default_tolerances_leave_a_tail_orders_above_the_converged_one_that_shrinks_with_the_tolerance():
    # the paper's KP = 3.9e6 case. Only amplitudes are asserted: whether the loose-tolerance tail is
    # classed "decay" or "quasi-periodic" depends on the processor's rounding (README, "The paper's solver")
    from millvib_env.analysis.solver_study import SOLVERS, run_solver_study, verdicts

    kp_study = PAPER_STUDIES[2]
    tight = next(s for s in SOLVERS if s.name == "RK45 1e-6")
    rows, _ = run_solver_study(1.0, solvers=(SOLVERS[0], tight, SOLVERS[-1]), progress=False, keep_runs=False,
                               cases=[(kp_study, kp_study.cases[2])])
    default, tighter, converged = rows
    assert converged.motion == "decay"
    assert default.tail_ptp_um > 100 * converged.tail_ptp_um      # measured 7e4 and 2e5 on two machines
    assert default.tail_ptp_um > 100 * tighter.tail_ptp_um        # measured 2e3 and 6e3
    assert verdicts(rows)[0]["verdict"].startswith("artefact")


def test_the_studies_in_processes_give_the_numbers_of_one_process():
    """`millvib reproduce --jobs N`: the stability map's cells and the solver study's runs are independent, so
    spawned processes give the same KP_crit and rows (wall times aside), and the runs come back whole (a run's
    auxiliary outputs are computed before it is pickled). Both pools' modules are declared first, as reproduce
    declares them (`distributed.expect_modules`)."""
    import dataclasses

    import numpy as np

    from millvib_env.analysis.linear import stability_map
    from millvib_env.analysis.solver_study import SOLVERS, run_solver_study
    from millvib_env.distributed import expect_modules

    case = (PAPER_STUDIES[0], PAPER_STUDIES[0].cases[0])
    runs = {}
    with expect_modules("millvib_env.analysis.linear", "millvib_env.analysis.solver_study"):
        one = stability_map([1.25e5, 2.25e6], [5e-16], friction="sliding")
        two = stability_map([1.25e5, 2.25e6], [5e-16], friction="sliding", processes=2)
        np.testing.assert_array_equal(one, two)
        for n in (1, 2):
            rows, runs[n] = run_solver_study(0.2, solvers=(SOLVERS[0], SOLVERS[2]), progress=False, cases=[case],
                                             processes=n)
            runs[n]["rows"] = [dataclasses.replace(r, wall_s=0.0) for r in rows]
    assert runs[1]["rows"] == runs[2]["rows"]
    for key in runs[1]:
        if key != "rows":
            np.testing.assert_array_equal(runs[1][key].states, runs[2][key].states)
            np.testing.assert_array_equal(runs[1][key].aux, runs[2][key].aux)


@pytest.mark.slow  # short studies and maps, drawn: seconds
def test_reproduces_figures_keep_every_text_inside_and_their_panels_apart(monkeypatch, tmp_path):
    """Reproduce's figures are placed at fixed margins (`_figures.panel_grid`): the studies' time and phase plots,
    their severity bars, the motion and stability maps and the solver study's two figures keep their texts inside
    and their panels apart (`tests._figures`), on short runs and coarse maps."""
    import matplotlib.pyplot as plt

    import millvib_env.analysis.paper as paper
    import millvib_env.analysis.solver_study as study
    from tests._figures import texts_inside_and_panels_apart

    drawn = []
    for module in (paper, study):
        monkeypatch.setattr(module, "save_figure", lambda fig, path, dpi=110: drawn.append(fig) or path)
    paper.reproduce(tmp_path / "r", t_end=0.1, map_resolution=3, progress=False, solver_study=False)
    case = (PAPER_STUDIES[0], PAPER_STUDIES[0].cases[0])
    rows, runs = study.run_solver_study(0.2, solvers=(study.SOLVERS[0], study.SOLVERS[-1]), progress=False,
                                        cases=[case])
    study.plot_solver_study(rows, runs, tmp_path)
    assert len(drawn) == 10
    for fig in drawn:
        texts_inside_and_panels_apart(fig)
        plt.close(fig)


def test_reproduce_without_figures_writes_the_numbers_alone(tmp_path):
    """`millvib reproduce --no-figures`: the cases' CSV and summary.json, no PNG (the test above draws the
    figures)."""
    import json

    import millvib_env.analysis.paper as paper

    paper.reproduce(tmp_path / "a", t_end=0.1, maps=False, solver_study=False, progress=False, figures=False)
    assert sorted(p.name for p in (tmp_path / "a").iterdir() if not p.name.startswith(".")) == \
        ["paper_cases.csv", "summary.json"]
    assert len(json.loads((tmp_path / "a" / "summary.json").read_text())["cases"]) == 9


def test_reproduce_runs_the_motion_map_on_a_thread_with_the_numbers_of_a_serial_run(tmp_path, monkeypatch):
    """`reproduce` simulates the motion map's plants on a thread beside its other steps (the kernels release the
    GIL): its map is the one the same plants give serially in the caller's thread, and its files are listed in
    the paper's order."""
    import millvib_env.analysis.paper as paper
    from millvib_env import threads

    summary = paper.reproduce(tmp_path / "a", t_end=0.1, map_resolution=3, progress=False, solver_study=False,
                              figures=False)
    assert [p.rsplit("/", 1)[-1] for p in summary["files"]] == \
        ["paper_cases.csv", "motion_map_c1_kp.csv", "stability_map.csv", "summary.json"]
    monkeypatch.setenv(threads.THREADS_ENV, "1")
    (tmp_path / "b").mkdir()
    paper._motion_map(tmp_path / "b", paper._motion_runs(0.1, 3, 7), figure=False)
    name = "motion_map_c1_kp.csv"
    assert (tmp_path / "a" / name).read_bytes() == (tmp_path / "b" / name).read_bytes()
