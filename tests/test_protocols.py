"""The typed contracts (issue 10): every shipped model kind satisfies `gma_ffc.protocols.Model`
and its steppers the stepper protocols, and the three shipped drivers satisfy `DriverProtocol`.

Two checks, as each sees something the other does not: `isinstance` against the
runtime-checkable protocols here (member names, on real objects), and `_signatures_match` below,
which mypy type-checks in CI (this file is in `[tool.mypy] files`): the signatures, which
`isinstance` cannot see.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from gma_ffc import modelio
from gma_ffc.control.config import load_config
from gma_ffc.drivers import Driver, DriverProtocol, driver_class
from gma_ffc.drivers.modbus import ModbusDriver
from gma_ffc.drivers.serial import SerialDriver
from gma_ffc.drivers.sim import SimDriver
from gma_ffc.errors import ConfigError
from gma_ffc.model import SDPIModel
from gma_ffc.modelio import load_model
from gma_ffc.protocols import ForwardStepper, InverseStepper, Model

ROOT = Path(__file__).resolve().parents[1]
MODELS = {"sdpi": ROOT / "config" / "models" / "sim_sdpi.yaml", "mpi": ROOT / "config" / "models" / "sim_mpi_11MPa.yaml"}
DRIVER_CONFIGS = {"sim": "sim.yaml", "modbus": "modbus_tcp.yaml", "serial": "serial.yaml"}


def _signatures_match(sdpi: SDPIModel, sim: SimDriver, modbus: ModbusDriver, serial: SerialDriver) -> None:
    """Never called: mypy checks these assignments against the protocols' signatures."""
    model: Model = sdpi
    forward: ForwardStepper = sdpi.forward_stepper(1e-3)
    inverse: InverseStepper = sdpi.inverse_stepper(1e-3)
    drivers: list[DriverProtocol] = [sim, modbus, serial]
    classes: list[type[DriverProtocol]] = [SimDriver, ModbusDriver, SerialDriver]
    del model, forward, inverse, drivers, classes


def _models() -> list[Model]:
    sdpi, mpi = load_model(MODELS["sdpi"]), load_model(MODELS["mpi"])
    # The diagnose tool's extended model, found the way model files find it (its module may move).
    extended = modelio._class_for("extended")(sdpi)
    return [sdpi, mpi, extended]


@pytest.mark.parametrize("index, kind", [(0, "sdpi"), (1, "mpi"), (2, "extended")])
def test_every_model_kind_satisfies_the_model_protocol(index, kind):
    model = _models()[index]
    assert model.kind == kind
    assert isinstance(model, Model)
    assert isinstance(model.forward_stepper(1e-3, 0.5), ForwardStepper)
    assert isinstance(model.inverse_stepper(1e-3, 0.5), InverseStepper)
    assert isinstance(model.preview_s, float) and model.preview_s >= 0.0
    lo, hi = model.drive_range
    assert lo < hi


@pytest.mark.parametrize("kind", sorted(DRIVER_CONFIGS))
def test_every_shipped_driver_satisfies_the_driver_protocol(kind):
    cfg = load_config(ROOT / "config" / DRIVER_CONFIGS[kind])
    cls = driver_class(kind)
    driver = cls(cfg.driver, cfg.period_s)            # constructed, not opened: nothing is contacted
    assert issubclass(cls, Driver) and isinstance(driver, DriverProtocol)


class _NotADriver:
    kind = "half"

    def open(self) -> None:
        pass


def test_a_plugin_without_the_base_class_must_offer_the_whole_contract(monkeypatch):
    """A lab's driver need not subclass Driver, but one that lacks members is refused, by name."""
    from importlib.metadata import EntryPoint

    import gma_ffc.drivers as drivers

    ep = EntryPoint("half", f"{__name__}:_NotADriver", drivers.GROUP)
    monkeypatch.setattr(drivers, "available_drivers", lambda: {"half": ep})
    with pytest.raises(ConfigError, match="neither subclasses gma_ffc.drivers.Driver nor defines validate_config, "
                                          "activate, read, write, safe, deactivate, close, reconnect, health"):
        driver_class("half")
