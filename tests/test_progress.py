"""Progress reads at a glance (issue 11): stage, fraction and elapsed time within 80 columns on a
terminal; a plain line per stage when piped, never silence."""

from __future__ import annotations

import io

from gma_ffc.progress import WIDTH, Progress


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_terminal_line_has_stage_fraction_time_and_fits_80_columns():
    out = FakeTTY()
    with Progress("diagnose", total=4, stream=out) as p:
        p.advance(note="round 1: fitting rate_dependence, mechanical_dynamics, thermal_drift, creep, time_delay")
        p.advance(2)
        p.advance(note="writing report")
    frames = [f for f in out.getvalue().replace("\n", "\r").split("\r") if f]
    assert frames and all(len(f.replace("\x1b[K", "")) <= WIDTH for f in frames)
    assert any("[4/4, 100 %]" in f for f in frames) and any(" s " in f for f in frames)
    assert out.getvalue().endswith("\n")


def test_piped_output_is_quiet_by_contract_and_a_plain_line_per_stage_on_request(monkeypatch):
    quiet = io.StringIO()
    with Progress("identify", total=3, stream=quiet) as p:
        p.advance(note="step 1")
    assert quiet.getvalue() == ""
    monkeypatch.setenv("GMA_FFC_PROGRESS", "lines")
    out = io.StringIO()
    with Progress("identify", total=3, stream=out) as p:
        p.advance(note="step 1")
        p.advance(note="step 1")            # same stage: no new line
        p.advance(note="step 2")
    lines = out.getvalue().splitlines()
    assert lines[0].startswith("identify: step 1 (1/3") and lines[1].startswith("identify: step 2 (3/3")
    assert lines[-1].startswith("identify: done") and "\r" not in out.getvalue()


def test_identify_says_why_its_steps_come_again_and_never_claims_100_percent_first(tmp_path, monkeypatch, capsys):
    """A recording that sweeps its drive late is fitted twice; the progress showed [4/4, 100 %]
    and then 'step 1' again (a new user's sweep, 2026-11-30)."""
    import numpy as np

    from gma_ffc.cli import main
    from gma_ffc.modelio import load_model
    from gma_ffc.recordings import Recording, write_recording

    model = load_model("config/models/sim_sdpi.yaml")
    lo, hi = model.drive_range
    t = np.arange(0, 1.75, 1e-3)
    i = 0.5 * (lo + hi) + 0.5 * (hi - lo) * np.sin(2 * np.pi * 1.0 * t)      # starts mid-range: sweeps late
    stress = np.full(t.size, -15.2)
    y = model.simulate(t, i, stress)
    write_recording(tmp_path / "late.csv", Recording({"time_s": t, "current_A": i, "stress_MPa": stress,
                                                      "displacement_um": y}, {}, "late.csv"))
    monkeypatch.setenv("GMA_FFC_PROGRESS", "lines")
    assert main(["identify", str(tmp_path / "late.csv"), "-o", str(tmp_path / "m.yaml")]) == 0
    err = capsys.readouterr().err
    assert "fit again, start states estimated: step 1" in err and "100 %" not in err, err
