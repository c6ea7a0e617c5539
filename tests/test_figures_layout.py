"""Every figure a person reads first (identify, demo, diagnose report) passes the reader's check:
no overlapping text, no legend on the data, both axes labelled with a unit (issue 11)."""

from __future__ import annotations

import numpy as np
import pytest

from figure_layout import layout_problems



@pytest.fixture(scope="module")
def bench():
    from benchmarks import cases as sil_cases

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
def test_diagnose_report_figures(diagnosed, case):
    from gma_ffc.diagnose import report

    _, _, dg = diagnosed(case, 0.5)
    for plot in (report.plot_residuals, report.plot_overlays, report.plot_loops, report.plot_candidates):
        fig = plot(dg, render=lambda f: f)
        assert layout_problems(fig) == [], plot.__name__


def _record_with_pause_and_steps():
    """2 kHz: 0-4 s a 5 Hz sine over the full range, 4-8 s a pause at zero drive, 8-12 s a
    staircase of holds (0, 0.5, 1.5, 0 A) -- the drive users record for a diagnosis."""
    from types import SimpleNamespace

    t = np.arange(0.0, 12.0, 5e-4)
    u = np.where(t < 4.0, 0.9 - 0.9 * np.cos(2 * np.pi * 5 * t), 0.0)
    stairs = (t >= 8.0) & (t < 12.0)
    u[stairs] = np.array([0.0, 0.5, 1.5, 0.0])[((t[stairs] - 8.0) // 1.0).astype(int)]
    return SimpleNamespace(t=t, u=u, y=np.zeros_like(t), settled=0)


def test_loop_panel_shows_a_window_where_the_drive_sweeps_a_loop():
    """The residual is largest in the pause and the staircase; a loop drawn there is a blob or a line.
    The loop panel shows where the drive sweeps, and among those windows where the score is highest."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.report import _shown

    d = _record_with_pause_and_steps()
    loc = SimpleNamespace(window_s=(4.0, 6.0))                  # located in the pause
    score = np.where(d.t >= 4.0, 10.0, 0.0) + np.where(d.t < 2.0, 0.0, 1.0)  # the sine's second half scores higher
    w, sweeps = _shown(d, loc, score, sweep=True)
    assert sweeps
    assert 2.0 <= d.t[w.start] and d.t[w.stop - 1] <= 4.0
    assert np.ptp(d.u[w]) > 0.9 * np.ptp(d.u)
    # without the sweep condition the same score picks the pause or the staircase
    w_any, _ = _shown(d, loc, score, sweep=False)
    assert d.t[w_any.start] >= 4.0


def test_with_nothing_named_the_loop_panel_shows_the_located_window_where_it_sweeps():
    """"Loops where the residual is largest" drew t = 5.6-7.1 s while the text located t = 1.5-3.0 s
    (a new user's sweep, 2026-11-30): with nothing named, the located window is drawn where its drive
    sweeps a loop, and only a located window without one makes the panel look elsewhere."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.report import _located_loops

    d = _record_with_pause_and_steps()
    elsewhere = np.where((d.t > 2.5) & (d.t < 3.5), 5.0, 0.0)      # the final model's residual peaks elsewhere
    w, sweeps = _located_loops(d, SimpleNamespace(window_s=(1.0, 1.6)), d.y - elsewhere)
    assert sweeps and abs(d.t[w.start] - 1.0) < 1e-3
    w, sweeps = _located_loops(d, SimpleNamespace(window_s=(4.5, 6.5)), d.y - elsewhere)   # a pause: no loop
    assert sweeps and 2.0 <= d.t[w.start] <= 3.5


def test_loop_panel_says_so_when_no_window_sweeps():
    from types import SimpleNamespace

    from gma_ffc.diagnose.report import _shown

    d = _record_with_pause_and_steps()
    keep = d.t >= 4.0
    d = SimpleNamespace(t=d.t[keep], u=d.u[keep], y=d.y[keep], settled=0)
    loc = SimpleNamespace(window_s=(9.0, 11.0))
    w, sweeps = _shown(d, loc, np.ones_like(d.t), sweep=True)
    assert not sweeps
    assert abs(d.t[w.start] - 9.0) < 1e-3                       # the located window, said to sweep nothing


def test_loop_panel_of_a_slow_drive_holds_a_whole_cycle():
    """A 1 Hz sine at 5 kHz located in a 0.8 s window: the loop is drawn out and back, not half of it."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.report import _shown

    t = np.arange(0.0, 10.0, 2e-4)
    d = SimpleNamespace(t=t, u=150 * np.sin(2 * np.pi * t), y=np.zeros_like(t), settled=0)
    w, sweeps = _shown(d, SimpleNamespace(window_s=(4.5, 5.3)), np.ones_like(t), sweep=True)
    assert sweeps and t[w.stop - 1] - t[w.start] >= 1.0


def test_identify_plot_scores_what_the_table_scores(tmp_path):
    """A recording that reaches both drive ends only late is fitted on every sample: the table said
    RMS 0.1036 um, the plot's title 0.083 um (after the first sweep) and greyed a stretch 'not fitted'."""
    from gma_ffc.identify import SDPIIdentifier
    from gma_ffc.plots import plot_loops
    from hil_sim.record import make_recording

    rec = make_recording("identification", seed=2, effects=["noise"], stress_MPa=-15.2)
    t = rec.time_s
    cut = rec.rows((t > 0.1 * t[-1]) & (t < 0.45 * t[-1]), "cut.csv")   # its first sweep is 40 % of it
    ident = SDPIIdentifier().fit([cut])
    fit = ident.report_[0]
    assert fit.fitted_from == 0                       # every sample fitted, as identify's note says
    fig = plot_loops(ident.model_, [cut], fitted_from=[f.fitted_from for f in ident.report_])
    title = next(ax.get_title() for ax in fig.axes if "RMS" in ax.get_title())
    assert f"RMS {fit.rms_um:.4f} um" in title, (title, fit)
    assert ("not fitted" in fig._suptitle.get_text()) == (fit.fitted_from > 0)


def test_the_residual_plot_is_scaled_to_the_scored_samples_not_the_settling_start():
    """On a measured piezo the unscored start swung to -35 um and flattened the ~1 um residual the
    diagnosis judged into a line (a new user's sweep, 2026-11-30)."""
    from types import SimpleNamespace

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gma_ffc.diagnose.report import _scale_to_scored

    t = np.linspace(0.0, 10.0, 2001)
    residual = np.sin(2 * np.pi * t)                         # +-1 um where scored
    residual[t < 1.0] = -35.0 * np.exp(-t[t < 1.0])           # the settling start, unscored
    fig, ax = plt.subplots()
    ax.plot(t, residual)
    _scale_to_scored(ax, SimpleNamespace(mask=t >= 1.0), [residual])
    lo, hi = ax.get_ylim()
    assert -1.3 < lo < -0.99 and 0.99 < hi < 1.3
    plt.close(fig)


def test_a_panel_at_rest_is_not_cut_to_a_few_samples_by_the_drive_sensor_noise():
    """A long run's 3 Hz sine, then 0 A held (the coil cooling): the before-and-after panel 'where the
    named effects help most' drew 18 ms at t = 150.04 s, flat lines under an axis reading
    '0.040 ... +1.5e2': the noise of the measured current at rest crossed the middle of its own
    swing often enough to count as ten drive cycles, and the window was cut to them."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.report import _window

    t = np.arange(0.0, 20.0, 1e-3)
    noise = np.random.default_rng(0).normal(0.0, 0.001, t.size)
    u = np.where(t < 10.0, 1.5 - 1.5 * np.cos(2 * np.pi * 3 * t), 0.0) + noise
    d = SimpleNamespace(t=t, u=u, y=np.zeros_like(t), settled=0)
    rest = _window(d, (10.5, 14.5))
    assert t[rest.stop - 1] - t[rest.start] > 1.0                 # the held drive as located, not 20 samples
    sine = _window(d, (2.0, 6.0))                                  # about five cycles of the sine, as before
    assert 1.3 < t[sine.stop - 1] - t[sine.start] < 2.0


def test_a_time_axis_late_in_a_long_run_shows_the_times_not_an_offset():
    """Ticks '0.040 ... +1.5e2' under 'time (s)' read as 0.04 s; the report's time axes show 150.04."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gma_ffc.diagnose.report import _time_axis

    fig, ax = plt.subplots()
    ax.plot([150.037, 150.055], [1.0, 2.0])
    _time_axis(ax)
    fig.canvas.draw()
    assert ax.xaxis.get_offset_text().get_text() == "" and ax.get_xlabel() == "time (s)"
    assert any(lab.get_text().startswith("150.0") for lab in ax.get_xticklabels())
    plt.close(fig)


def test_a_recording_the_named_effects_do_not_help_is_not_titled_where_they_help_most():
    """Four recordings diagnosed together, effects named: on one of them (a 30 Hz sine) the extended
    model missed by more than the base (RMS 0.211 against 0.176 um in the panel's own legend),
    under the title 'where the named effects help most'. The title says they do not help there."""
    from types import SimpleNamespace

    from gma_ffc.diagnose.report import plot_overlays

    t = np.arange(0.0, 2.0, 1e-3)
    u = 1.5 - 1.5 * np.cos(2 * np.pi * 3 * t)
    y = 10.0 * u
    rng = np.random.default_rng(1)
    helped = SimpleNamespace(name="helped.csv", t=t, u=u, y=y, settled=0)
    hurt = SimpleNamespace(name="hurt.csv", t=t, u=u, y=y, settled=0)
    loc = SimpleNamespace(window_s=(0.5, 1.0))
    dg = SimpleNamespace(data=[helped, hurt], located=[loc, loc], verdict=["creep"],
                         base_predictions=[y + 1.0, y + 0.1 * rng.normal(size=t.size)],
                         final_predictions=[y + 0.1, y + 0.3 * rng.normal(size=t.size)])
    fig = plot_overlays(dg, render=lambda f: f)
    titles = [ax.get_title() for ax in fig.axes[::2]]
    assert titles[0] == "helped.csv: where the named effects help most"
    assert "help most" not in titles[1] and "do not help" in titles[1], titles
