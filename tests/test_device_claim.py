"""One controller per amplifier, machine-wide (`gma_ffc.control.device_claim`)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import uuid
from pathlib import Path

import pytest
import yaml

from gma_ffc.control.config import validate_config
from gma_ffc.control.device_claim import DeviceClaim
from gma_ffc.control.manager import ControllerManager
from gma_ffc.drivers.modbus import ModbusDriver
from gma_ffc.drivers.sim import SimDriver
from gma_ffc.errors import ConfigError

from test_controller_faults import make, models  # noqa: F401  (fixture reused)

ROOT = Path(__file__).resolve().parents[1]


def _device() -> str:
    return f"test:amp-{uuid.uuid4().hex}"          # unique per test: claims are machine-wide


def test_a_second_claim_on_a_device_is_refused_naming_the_holder_and_free_once_released():
    device = _device()
    first, second = DeviceClaim([device]), DeviceClaim([device])
    first.acquire()
    with pytest.raises(ConfigError, match=rf"{device} is driven by another controller on this machine "
                                          rf"\(pid {os.getpid()}\).*Stop that one first: 'kill {os.getpid()}' \(SIGTERM\)"):
        second.acquire()
    first.release()
    second.acquire()
    second.release()


def test_a_claim_dies_with_its_process_even_on_kill_9():
    device = _device()
    holder = subprocess.Popen([sys.executable, "-c", (
        "import sys, time; from gma_ffc.control.device_claim import DeviceClaim; "
        f"c = DeviceClaim([{device!r}]); c.acquire(); print('held', flush=True); time.sleep(60)")],
        stdout=subprocess.PIPE, text=True, cwd=ROOT)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(ConfigError, match=rf"pid {holder.pid}\)"):
            DeviceClaim([device]).acquire()
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait(10)
    claim = DeviceClaim([device])
    claim.acquire()
    claim.release()


class _ClaimingSim(SimDriver):
    """The sim driver, standing for an amplifier with a name (a real driver's `amplifiers`)."""

    device = ""

    @classmethod
    def amplifiers(cls, cfg):
        return [cls.device]


def test_a_second_controller_on_the_same_amplifier_is_refused_before_its_driver_opens(models, tmp_path):
    """Two controllers (two configs, two telemetry files) on one Modbus amplifier both drove it,
    and the second's stop switched the first's output off (a new user's sweep, 2026-11-30)."""
    _ClaimingSim.device = _device()
    _, _, cfg = make(tmp_path, models)
    first = ControllerManager(cfg, model=models[0], driver=_ClaimingSim(cfg.driver, cfg.period_s))
    other = validate_config({**cfg.raw, "telemetry": {"path": str(tmp_path / "other.csv")}})
    opened = []
    driver = _ClaimingSim(other.driver, other.period_s)
    driver.open = lambda: opened.append(True)                # type: ignore[method-assign]
    second = ControllerManager(other, model=models[0], driver=driver)
    first.claim_outputs()
    try:
        with pytest.raises(ConfigError, match="is driven by another controller"):
            second.claim_outputs()
        summary = second.run(duration_s=0.1)
        assert not opened and summary["state"] == "fault" and "driven by another controller" in summary["exit_reason"]
    finally:
        first.release_outputs()
    driver = _ClaimingSim(other.driver, other.period_s)
    again = ControllerManager(other, model=models[0], driver=driver).run(duration_s=0.1)
    assert again["state"] == "stopped", again["exit_reason"]      # free once the first let go


def test_the_modbus_amplifier_is_named_by_its_link_and_unit():
    raw = yaml.safe_load((ROOT / "config" / "modbus_tcp.yaml").read_text())
    cfg = validate_config(raw, base_dir=ROOT / "config")
    assert ModbusDriver.amplifiers(cfg.driver) == ["modbus-tcp:127.0.0.1:5020:unit1"]


def test_a_tcp_amplifier_is_named_by_every_address_its_host_resolves_to():
    """`localhost` and `127.0.0.1` are one amplifier: the claim compared the host as text, and a
    second controller with `host: localhost` drove the amplifier a first drove at 127.0.0.1."""
    from gma_ffc.drivers.modbus import tcp_link_names

    by_name, by_ip = tcp_link_names("localhost", 5020), tcp_link_names("127.0.0.1", 5020)
    assert by_ip == ["modbus-tcp:127.0.0.1:5020"]
    assert "modbus-tcp:127.0.0.1:5020" in by_name and "modbus-tcp:localhost:5020" not in by_name
    assert tcp_link_names("no-such-host.invalid", 5020) == ["modbus-tcp:no-such-host.invalid:5020"]


def test_a_claim_by_localhost_is_refused_while_127_0_0_1_holds_the_amplifier():
    from gma_ffc.drivers.modbus import tcp_link_names

    port = 20000 + uuid.uuid4().int % 40000                     # unique per run: claims are machine-wide
    first = DeviceClaim([f"{n}:unit1" for n in tcp_link_names("127.0.0.1", port)])
    first.acquire()
    try:
        with pytest.raises(ConfigError, match=rf"modbus-tcp:127.0.0.1:{port}:unit1 is driven by another controller"):
            DeviceClaim([f"{n}:unit1" for n in tcp_link_names("localhost", port)]).acquire()
    finally:
        first.release()
