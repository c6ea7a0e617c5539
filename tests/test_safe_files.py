"""Files the service writes (issue 33): never through a symbolic link, never over a file that is
not its own, never outside the folders the config names. Each refusal is one line naming the
path, exit 2, and the file it would have hit is unchanged."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
from pathlib import Path

import pytest

from gma_ffc import safe_files
from gma_ffc.cli import main
from gma_ffc.control.learned_file import save_learned
from gma_ffc.control.telemetry import Telemetry
from gma_ffc.safe_files import OutputRefused

ROOT = Path(__file__).resolve().parents[1]
MODEL = ROOT / "config" / "models" / "sim_sdpi.yaml"
VICTIM_TEXT = "precious: not the controller's\n"


def write_config(path: Path, telemetry: str, extra: str = "") -> Path:
    path.write_text(f"""\
rate_hz: 200
clock: simulated
model: {MODEL}
driver: {{kind: sim, load_mass_kg: 15.3}}
reference: {{kind: sine, frequency_hz: 3.0, amplitude_um: 5.0, offset_um: 6.0}}
limits: {{current_min_A: 0.0, current_max_A: 2.0, slew_A_per_s: 200.0}}
telemetry: {{path: {telemetry}}}
{extra}""")
    return path


@pytest.fixture
def victim(tmp_path: Path) -> Path:
    """A file someone else cares about, outside every folder the service may write."""
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    path = outside / "victim.txt"
    path.write_text(VICTIM_TEXT)
    return path


def run_refused(capsys, *args: str) -> str:
    """`gma-ffc run ...` in this process: exit 2 and one line on stderr, which is returned."""
    code = main(["run", *args, "--no-socket", "--duration", "0.2"])
    err = capsys.readouterr().err.strip().splitlines()
    err = [line for line in err if ": error: " in line or "Traceback" in line]
    assert code == 2 and len(err) == 1 and "Traceback" not in err[0], (code, err)
    return err[0]


@pytest.mark.parametrize("link", ["tel.csv", "tel.csv.lock"])
def test_telemetry_or_its_lock_through_a_symlink_is_refused(tmp_path, victim, capsys, link):
    """The lock file was opened and truncated through any link: /etc/passwd, for a root service."""
    out = tmp_path / "out"
    out.mkdir()
    (out / link).symlink_to(victim)
    cfg = write_config(tmp_path / "rig.yaml", str(out / "tel.csv"))
    line = run_refused(capsys, "--config", str(cfg))
    assert f"{out / link} is a symbolic link" in line
    assert victim.read_text() == VICTIM_TEXT


def test_an_existing_file_that_is_not_this_rigs_telemetry_is_kept(tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    recording = out / "tel.csv"
    recording.write_text("# source: hil_sim recorder\ntime_s,current_A,displacement_um\n0,0,0\n")
    cfg = write_config(tmp_path / "rig.yaml", str(recording))
    line = run_refused(capsys, "--config", str(cfg))
    assert f"{recording} exists and is not a telemetry file of this rig" in line and "move it away" in line
    assert recording.read_text().startswith("# source: hil_sim recorder")
    # another rig's telemetry (another config) is not this rig's either
    recording.write_text(f"# source: gma-ffc controller\n# config: {tmp_path / 'other_rig.yaml'}\ntime_s\n0\n")
    assert "is not a telemetry file of this rig" in run_refused(capsys, "--config", str(cfg))


def test_a_copied_config_is_told_of_its_missing_model_before_its_telemetry(tmp_path, capsys):
    """A config copied to another folder with its telemetry still on the first rig's file: the run
    named the telemetry first, and only once that was mended the model the copy had lost (a new
    user's two rounds, 2026-11-30). The missing input comes first, named by its config key, and
    following its advice leads to the telemetry's refusal, not to the same line again."""
    out = tmp_path / "out"
    out.mkdir()
    recording = out / "tel.csv"
    recording.write_text(f"# source: gma-ffc controller\n# config: {tmp_path / 'rig1.yaml'}\ntime_s\n0\n")
    copied = tmp_path / "copy"
    copied.mkdir()
    cfg = write_config(copied / "rig2.yaml", str(recording))
    cfg.write_text(cfg.read_text().replace(f"model: {MODEL}", "model: models/sim_sdpi.yaml"))
    line = run_refused(capsys, "--config", str(cfg))
    assert f"{copied / 'models' / 'sim_sdpi.yaml'}: no such file (config key 'model'" in line
    assert "relative path resolves against the config's folder" in line
    (copied / "models").mkdir()
    (copied / "models" / "sim_sdpi.yaml").write_bytes(MODEL.read_bytes())      # the advice, followed
    assert "is not a telemetry file of this rig" in run_refused(capsys, "--config", str(cfg))


def _start_of(path: Path) -> str:
    return next(line for line in path.read_text().splitlines() if line.startswith("# start_unix_s"))


def test_a_restart_keeps_the_earlier_runs_telemetry_and_the_oldest_beyond_keep_goes(tmp_path, caplog):
    """A restart truncated its rig's telemetry: the run that failed before it was lost (a new user's
    sweep, 2026-11-30: 2,567 lines cut to 501 without a word). Now each run's file moves aside."""
    caplog.set_level(logging.INFO, logger="gma_ffc.control.telemetry")
    cfg = write_config(tmp_path / "rig.yaml", "tel.csv", "")
    cfg.write_text(cfg.read_text().replace("telemetry: {path: tel.csv}", "telemetry: {path: tel.csv, keep_previous: 2}"))
    starts = []
    for _ in range(4):
        assert main(["run", "--config", str(cfg), "--no-socket", "--duration", "0.2"]) == 0
        starts.append(_start_of(tmp_path / "tel.csv"))
    assert _start_of(tmp_path / "tel.1.csv") == starts[2] and _start_of(tmp_path / "tel.2.csv") == starts[1]
    assert not (tmp_path / "tel.3.csv").exists() and len(set(starts)) == 4
    assert f"kept as {tmp_path / 'tel.1.csv'}" in caplog.text


def test_keep_previous_0_overwrites_as_before(tmp_path):
    cfg = write_config(tmp_path / "rig.yaml", "tel.csv")
    cfg.write_text(cfg.read_text().replace("telemetry: {path: tel.csv}", "telemetry: {path: tel.csv, keep_previous: 0}"))
    for _ in range(2):
        assert main(["run", "--config", str(cfg), "--no-socket", "--duration", "0.2"]) == 0
    assert (tmp_path / "tel.csv").read_text().count("# source: gma-ffc controller") == 1
    assert not (tmp_path / "tel.1.csv").exists()


@pytest.mark.parametrize("what", ["someone's data", "a link"])
def test_a_kept_name_that_is_not_this_rigs_telemetry_is_refused_before_anything_moves(tmp_path, victim, capsys, what):
    cfg = write_config(tmp_path / "rig.yaml", "tel.csv")
    assert main(["run", "--config", str(cfg), "--no-socket", "--duration", "0.2"]) == 0
    first = (tmp_path / "tel.csv").read_text()
    kept = tmp_path / "tel.1.csv"
    if what == "a link":
        kept.symlink_to(victim)
    else:
        kept.write_text(VICTIM_TEXT)
    line = run_refused(capsys, "--config", str(cfg))
    assert str(kept) in line and ("symbolic link" in line or "is not a telemetry file of this rig" in line), line
    assert (tmp_path / "tel.csv").read_text() == first and victim.read_text() == VICTIM_TEXT
    assert what == "a link" or kept.read_text() == VICTIM_TEXT


def test_this_rigs_telemetry_is_its_own_however_the_config_was_named(tmp_path, monkeypatch):
    """The demo ran its configs by a relative path; `gma-ffc run` names them by an absolute one. A
    run of the same config from another folder, or by either name, is still this rig's: it was
    refused as another rig's."""
    (tmp_path / "rig").mkdir()
    cfg = write_config(tmp_path / "rig" / "rig.yaml", "tel.csv")
    telemetry = tmp_path / "rig" / "tel.csv"
    monkeypatch.chdir(tmp_path)
    assert main(["run", "--config", "rig/rig.yaml", "--no-socket", "--duration", "0.2"]) == 0
    monkeypatch.chdir(tmp_path / "rig")
    assert main(["run", "--config", "rig.yaml", "--no-socket", "--duration", "0.2"]) == 0
    assert main(["run", "--config", str(cfg), "--no-socket", "--duration", "0.2"]) == 0
    # a file written before the source was recorded in full: its relative name, from where it ran
    text = telemetry.read_text()
    telemetry.write_text(text.replace(f"# config: {cfg}", "# config: rig.yaml", 1))
    assert "# config: rig.yaml" in telemetry.read_text()
    assert main(["run", "--config", str(cfg), "--no-socket", "--duration", "0.2"]) == 0
    assert telemetry.read_text().count("# source: gma-ffc controller") == 1


def test_telemetry_outside_the_named_output_dirs_is_refused(tmp_path, capsys):
    cfg = write_config(tmp_path / "rig.yaml", str(tmp_path / "elsewhere" / "tel.csv"),
                       f"output_dirs: [{tmp_path / 'data'}]\n")
    line = run_refused(capsys, "--config", str(cfg))
    assert "telemetry.path" in line and f"{tmp_path / 'elsewhere' / 'tel.csv'} is outside" in line
    assert not (tmp_path / "elsewhere").exists()


def test_a_linked_folder_leading_out_of_the_output_dirs_is_refused(tmp_path, victim, capsys):
    data = tmp_path / "data"
    data.mkdir()
    (data / "runs").symlink_to(victim.parent)            # data/runs -> elsewhere
    cfg = write_config(tmp_path / "rig.yaml", str(data / "runs" / "victim.txt"), f"output_dirs: [{data}]\n")
    line = run_refused(capsys, "--config", str(cfg))
    assert f"{data / 'runs' / 'victim.txt'} is outside" in line
    assert victim.read_text() == VICTIM_TEXT


def test_a_hard_link_to_another_file_is_refused(tmp_path, victim, capsys):
    out = tmp_path / "out"
    out.mkdir()
    os.link(victim, out / "tel.csv")
    cfg = write_config(tmp_path / "rig.yaml", str(out / "tel.csv"))
    assert "hard links" in run_refused(capsys, "--config", str(cfg))
    assert victim.read_text() == VICTIM_TEXT


def test_stats_snapshot_through_a_symlink_or_over_another_file_is_refused(tmp_path, victim, capsys):
    cfg = write_config(tmp_path / "rig.yaml", "tel.csv")
    link = tmp_path / "stats.json"
    link.symlink_to(victim)
    assert f"{link} is a symbolic link" in run_refused(capsys, "--config", str(cfg), "--stats-json", str(link))
    assert "is not a stats snapshot" in run_refused(capsys, "--config", str(cfg), "--stats-json", str(victim))
    assert victim.read_text() == VICTIM_TEXT


def test_learned_file_through_a_symlink_is_refused(tmp_path, victim, capsys):
    learned = tmp_path / "learned.yaml"
    learned.symlink_to(victim)
    cfg = write_config(tmp_path / "rig.yaml", "tel.csv", f"learning: {{kind: repetitive, file: {learned}}}\n")
    assert f"{learned} is a symbolic link" in run_refused(capsys, "--config", str(cfg))
    assert victim.read_text() == VICTIM_TEXT


def test_the_refusal_is_one_line_and_exit_2_from_the_installed_command(tmp_path, victim):
    out = tmp_path / "out"
    out.mkdir()
    (out / "tel.csv").symlink_to(victim)
    cfg = write_config(tmp_path / "rig.yaml", str(out / "tel.csv"))
    res = subprocess.run([sys.executable, "-m", "gma_ffc.cli", "run", "--config", str(cfg), "--duration", "1",
                          "--no-socket"], capture_output=True, text=True, timeout=120)
    assert res.returncode == 2 and res.stderr.count("\n") == 1, res.stderr
    assert res.stderr.startswith("gma-ffc run: error: ") and f"{out / 'tel.csv'} is a symbolic link" in res.stderr


# ---- the module itself: the same refusals where the writers open their files -------------------

def test_writers_refuse_at_open_time_too(tmp_path, victim):
    """Telemetry and the learned-file save go through safe_files when they open, not only in the
    service's check before the start (a link can appear in between)."""
    (tmp_path / "tel.csv").symlink_to(victim)
    tel = Telemetry(tmp_path / "tel.csv", ["time_s"], {"source": "gma-ffc controller", "config": "x"}, capacity=16)
    with pytest.raises(OutputRefused, match="is a symbolic link"):
        tel.start()
    assert not (tmp_path / "tel.csv.lock").is_symlink()

    class Learner:
        def to_dict(self):
            return {"format": "gma-ffc-learned-correction"}

    (tmp_path / "learned.yaml").symlink_to(victim)
    with pytest.raises(OutputRefused, match="is a symbolic link"):
        save_learned(Learner(), str(tmp_path / "learned.yaml"))
    victim.write_text("not a learned file\n")
    with pytest.raises(OutputRefused, match="is not a learned-correction file"):
        save_learned(Learner(), str(victim), (str(victim.parent),))
    save_learned(Learner(), str(tmp_path / "fresh.yaml"))                   # a new one is fine
    save_learned(Learner(), str(tmp_path / "fresh.yaml"))                   # and replacing our own
    assert "gma-ffc-learned-correction" in (tmp_path / "fresh.yaml").read_text()


def test_a_folder_swapped_for_a_link_after_the_check_is_not_followed(tmp_path, victim, monkeypatch):
    data = tmp_path / "data"
    (data / "runs").mkdir(parents=True)
    checked = safe_files.area_of(data / "runs" / "victim.txt", [data])      # (data, runs): fine then
    (data / "runs").rmdir()
    (data / "runs").symlink_to(victim.parent)                              # ... then swapped
    monkeypatch.setattr(safe_files, "area_of", lambda path, roots: checked)
    with pytest.raises(OutputRefused, match="became a link or is not a folder"):
        safe_files.open_for_writing(data / "runs" / "victim.txt", [data], safe_files.LEARNED)
    assert victim.read_text() == VICTIM_TEXT


def test_a_file_of_another_owner_is_refused(tmp_path):
    if os.geteuid() != 0:
        pytest.skip("needs root to create a file owned by another uid")
    path = tmp_path / "tel.csv"
    path.write_text("")
    os.chown(path, 65534, 65534)
    with pytest.raises(OutputRefused, match="belongs to uid 65534"):
        safe_files.open_for_writing(path, (), safe_files.TELEMETRY_LOCK)


def test_a_taken_telemetry_lock_advises_a_stop_that_reaches_the_holder(tmp_path):
    """The refusal said "stop it first ('gma-ffc stop', or 'kill PID')": for a holder started with
    --runtime-dir or --no-socket, 'gma-ffc stop' answered "no controller running". It advises the
    SIGTERM that reaches any holder; done, the lock is free."""
    import re
    import signal
    import textwrap

    from gma_ffc.control.telemetry import TelemetryLock
    from gma_ffc.errors import ConfigError

    tel = tmp_path / "tel.csv"
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import sys, time
        from gma_ffc.control.telemetry import TelemetryLock
        TelemetryLock({str(tel)!r}).acquire()
        print("held", flush=True)
        time.sleep(60)
        """)], stdout=subprocess.PIPE, text=True, cwd=Path(__file__).resolve().parents[1])
    try:
        assert holder.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError) as err:
            TelemetryLock(tel).acquire()
        words = str(err.value)
        assert "gma-ffc stop" not in words, words
        pid = int(re.search(r"'kill (\d+)' \(SIGTERM\)", words).group(1))
        assert pid == holder.pid
        os.kill(pid, signal.SIGTERM)                   # as advised
        holder.wait(10)
        lock = TelemetryLock(tel)
        lock.acquire()
        assert lock.held
        lock.release()
    finally:
        holder.kill()
        holder.wait()
