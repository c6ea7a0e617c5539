"""Every figure a person reads first (identify, demo, diagnose report) passes the reader's check:
no overlapping text, no legend on the data, both axes labelled with a unit (issue 11)."""

from __future__ import annotations

import numpy as np
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


def test_the_checker_sees_data_between_points_bars_and_neighbours():
    """What it once let through (each made by breaking a report plot on purpose): a legend on a
    two-point line, a legend on bars, a legend pushed out of its panel onto the next one, a label
    whose brackets hold a word rather than a unit."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def problems_of(draw):
        fig = plt.figure(figsize=(8, 3))             # no layout engine: it would move a panel away
        draw(fig)
        try:
            return layout_problems(fig)
        finally:
            plt.close(fig)

    def step(fig):                    # a step: no sample near the legend, the line runs under it
        ax = fig.subplots()
        ax.plot([0, 1, 1, 2], [0, 0, 1, 1], label="measured")
        ax.plot([0, 2], [0.5, 0.5], label="between")
        ax.set_xlabel("time (s)")
        ax.set_ylabel("displacement (um)")
        ax.legend(loc="center")
    assert any("legend covers data of 'between'" in p or "legend covers data of 'measured'" in p
               for p in problems_of(step))

    def bars(fig):
        ax = fig.subplots()
        ax.barh(["creep", "thermal_drift", "time_delay"], [1.0, 1.0, 1.0], label="held-out RMS")
        ax.axvline(0.2, ls=":", label="noise floor")
        ax.set_xlabel("held-out RMS (um)")
        ax.set_ylabel("candidate effect")
        ax.legend(loc="center")
    found = problems_of(bars)
    assert any("legend covers data" in p for p in found)
    assert not any("has no unit" in p for p in found)           # names on an axis need no unit

    def neighbour(fig):
        left, right = fig.subplots(1, 2)
        for ax in (left, right):
            ax.plot(np.linspace(0, 1, 50), np.linspace(0, 1, 50) ** 2, label="model")
            ax.set_xlabel("drive current (A)")
            ax.set_ylabel("displacement (um)")
        left.legend(loc="center", bbox_to_anchor=(1.75, 0.5))
    assert any("legend covers data of panel 1" in p for p in problems_of(neighbour))

    def fake_unit(fig):
        ax = fig.subplots()
        ax.plot([0, 1], [0, 1])
        ax.set_xlabel("time (s)")
        ax.set_ylabel("residual (fitted)")
    assert any("y label 'residual (fitted)' has no unit" in p for p in problems_of(fake_unit))


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
