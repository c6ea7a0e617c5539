"""Every figure a person reads first (identify, demo, diagnose report) passes the reader's check:
no overlapping text, no legend on the data, both axes labelled with a unit (issue 11)."""

from __future__ import annotations

import pytest

from figure_layout import layout_problems



@pytest.fixture(scope="module")
def bench():
    from gma_ffc import sil_cases

    return sil_cases


def test_the_checker_sees_what_a_reader_sees():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(2, 1, figsize=(4, 2.2))      # cramped, no layout engine
    for ax in axes:
        ax.plot(range(10), range(10), label="data")
        ax.set_title("a long title that runs into the ticks of the panel above it")
        ax.legend(loc="center")
    axes[0].set_xlabel("time")
    problems = layout_problems(fig)
    plt.close(fig)
    assert any("overlaps" in p for p in problems)
    assert any("legend covers data" in p for p in problems)
    assert any("no y axis label" in p for p in problems) and any("has no unit" in p for p in problems)


def test_identify_plot(bench):
    from gma_ffc.identify import SDPIIdentifier
    from gma_ffc.plots import plot_loops
    from hil_sim.record import make_recordings

    recs = make_recordings("identification", seed=1, effects=["noise"], stresses=(-11.3, -15.2, -19.1, -24.0))
    ident = SDPIIdentifier().fit(recs)
    fig = plot_loops(ident.model_, recs)
    assert layout_problems(fig) == []
    titles = [ax.get_title() for ax in fig.axes if ax.get_title()]
    table = [f"{f.stress_MPa:.4g} MPa" for f in ident.report_]        # what `identify` prints
    assert [t.split("  ")[0] for t in titles] == table


def test_demo_tracking_plot(tmp_path, monkeypatch):
    import gma_ffc.plots as plots
    from gma_ffc.cli.demo import run_demo

    figures = []
    monkeypatch.setattr(plots, "save_figure", lambda fig, path: figures.append(fig))
    run_demo(tmp_path / "demo")
    assert len(figures) == 3                                        # fit and two tracking plots
    for fig in figures:
        assert layout_problems(fig) == []


@pytest.mark.parametrize("case", ["thermal+delay", "null#1"])
def test_diagnose_report_figures(bench, case):
    from gma_ffc.diagnose import report
    from gma_ffc.diagnose.engine import diagnose

    cases = {c.name: c for c in bench.cases()}
    model, rec = bench.make_case(cases[case], scale=0.5)
    dg = diagnose(model, [rec])
    for plot in (report.plot_residuals, report.plot_overlays, report.plot_loops, report.plot_candidates):
        fig = plot(dg, render=lambda f: f)
        assert layout_problems(fig) == [], plot.__name__
