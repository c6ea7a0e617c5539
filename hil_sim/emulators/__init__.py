"""Device emulators speaking the real protocols (Modbus TCP, Modbus RTU over a pty, a SCPI-style
serial amplifier over a pty), so the controller's drivers reach the simulated GMA through the
same protocol stacks they use on hardware. Start one with `python -m hil_sim.emulators --help`,
or in-process:

    rig = EmulatedRig(make_plant())
    with ModbusEmulator(rig, load_register_map(DEFAULT_MAP), transport="tcp") as emu:
        host, port = emu.address
        rig.faults.set("nan:force_N")
        ...
        assert rig.last_setpoint_A == 0.0
"""

from __future__ import annotations

from pathlib import Path

from .control import ControlServer, send_control
from .faults import Fault, FaultSet, parse_fault
from .modbus import ModbusEmulator
from .plantsource import StandInPlant, make_plant
from .rig import Command, EmulatedRig
from .scpi import SerialAmplifierEmulator

DEVICE_CONFIGS = Path(__file__).resolve().parent.parent / "configs" / "devices"
DEFAULT_MAP = DEVICE_CONFIGS / "amplifier_int16.yaml"

__all__ = [
    "Command", "ControlServer", "DEFAULT_MAP", "DEVICE_CONFIGS", "EmulatedRig", "Fault", "FaultSet",
    "ModbusEmulator", "SerialAmplifierEmulator", "StandInPlant", "make_plant", "parse_fault",
    "send_control",
]
