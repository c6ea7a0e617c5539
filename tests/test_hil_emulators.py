"""Real clients (pymodbus TCP/RTU, pyserial) talk to the device emulators: register maps and word
orders from YAML, the setpoint reaches the plant, every fault mode behaves as configured and can be
cleared, and everything stops cleanly."""

from __future__ import annotations

import math
import os
import signal
import subprocess
import sys
import time

import pytest
import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient
from pymodbus.exceptions import ModbusException

from gma_ffc.errors import InputError
from gma_ffc.registers import RegisterMap, load_register_map
from hil_sim.emulators import (
    DEVICE_CONFIGS, ControlServer, EmulatedRig, ModbusEmulator, SerialAmplifierEmulator, StandInPlant,
    make_plant, parse_fault, send_control,
)
from hil_sim.emulators.control import execute
from hil_sim.emulators.faults import FaultSpecError
from hil_sim.emulators.modbus import encode_sensor

INT_MAP = DEVICE_CONFIGS / "amplifier_int16.yaml"
MIXED_MAP = DEVICE_CONFIGS / "multi_unit_mixed.yaml"
DEADLINE_S = 3.0


class ModbusFailure(Exception):
    """The device answered with a Modbus exception."""

    def __init__(self, response):
        super().__init__(str(response))
        self.code = getattr(response, "exception_code", None)


def read_channel(client, m: RegisterMap, name: str):
    ch = m[name]
    read = {"holding": client.read_holding_registers, "input": client.read_input_registers,
            "coil": client.read_coils, "discrete": client.read_discrete_inputs}[ch.function]
    response = read(ch.address, count=ch.count, device_id=ch.unit_id)
    if response.isError():
        raise ModbusFailure(response)
    return ch.decode(response.bits[:1] if ch.is_bit else response.registers)


def write_channel(client, m: RegisterMap, name: str, value) -> None:
    ch = m[name]
    words = ch.encode(value)
    if ch.function == "coil":
        response = client.write_coil(ch.address, bool(words[0]), device_id=ch.unit_id)
    else:
        response = client.write_registers(ch.address, words, device_id=ch.unit_id)
    if response.isError():
        raise ModbusFailure(response)


def wait_for(predicate, deadline_s: float = DEADLINE_S):
    """Poll until predicate() is truthy (bounded); returns its last value."""
    end = time.monotonic() + deadline_s
    value = predicate()
    while not value and time.monotonic() < end:
        time.sleep(0.02)
        value = predicate()
    return value


@pytest.fixture
def rig():
    return EmulatedRig(make_plant(seed=1), max_current_A=2.0)


def tcp_client(emu, timeout=1.0):
    client = ModbusTcpClient(emu.address[0], port=emu.address[1], timeout=timeout, retries=0)
    assert client.connect()
    return client


def rtu_client(emu, timeout=1.0):
    client = ModbusSerialClient(emu.address, baudrate=115200, timeout=timeout, retries=0)
    assert client.connect()
    return client


# ---- Modbus: the setpoint reaches the plant, through both maps and both transports ------------------

@pytest.mark.parametrize("transport", ["tcp", "rtu"])
@pytest.mark.parametrize("map_path", [INT_MAP, MIXED_MAP], ids=["int16_map", "mixed_units_map"])
def test_modbus_setpoint_reaches_plant_and_measured_current_follows(rig, transport, map_path):
    m = load_register_map(map_path)
    with ModbusEmulator(rig, m, transport=transport) as emu:
        client = tcp_client(emu) if transport == "tcp" else rtu_client(emu)
        try:
            write_channel(client, m, "current_setpoint_A", 1.2)
            write_channel(client, m, "output_enable", 1)
            assert read_channel(client, m, "current_setpoint_A") == pytest.approx(1.2, abs=1e-4)
            assert rig.setpoint_A == pytest.approx(1.2, abs=1e-4) and rig.output_enabled
            current = wait_for(lambda: abs(read_channel(client, m, "current_A") - 1.2) < 0.02)
            assert current, "measured current never followed the setpoint"
            # sensors decode (word orders, scales, units) to the plant's own values
            for name, tol in (("force_N", 0.2), ("displacement_um", 0.02)):
                reported = read_channel(client, m, name)
                assert reported == pytest.approx(rig.true_value(name), abs=tol + 0.02 * abs(rig.true_value(name)))
            assert rig.true_value("displacement_um") > 1.0  # the GMA elongated under 1.2 A
            # output off: the amplifier drives 0 A although the setpoint is held
            write_channel(client, m, "output_enable", 0)
            assert wait_for(lambda: abs(read_channel(client, m, "current_A")) < 0.02)
            assert rig.setpoint_A == pytest.approx(1.2, abs=1e-4)
        finally:
            client.close()
    kinds = [(c.kind, round(c.value, 3)) for c in rig.history()]
    assert kinds == [("setpoint", 1.2), ("output_enable", 1.0), ("output_enable", 0.0)]


def test_multi_unit_map_puts_channels_on_their_own_unit_ids(rig):
    m = load_register_map(MIXED_MAP)
    assert m.unit_ids == (1, 2, 3)
    with ModbusEmulator(rig, m) as emu:
        client = tcp_client(emu)
        try:
            ch = m["force_N"]
            ok = client.read_input_registers(ch.address, count=2, device_id=2)
            assert not ok.isError()
            wrong_unit = client.read_input_registers(ch.address, count=2, device_id=1)
            assert wrong_unit.isError() and wrong_unit.exception_code == 2  # not on the amplifier
            absent = client.read_input_registers(0, count=1, device_id=9)
            assert absent.isError()  # no such unit behind the gateway
        finally:
            client.close()


def test_modbus_refuses_bad_writes_and_unmapped_reads(rig):
    m = load_register_map(INT_MAP)
    with ModbusEmulator(rig, m) as emu:
        client = tcp_client(emu)
        try:
            with pytest.raises(ModbusFailure) as too_big:
                write_channel(client, m, "current_setpoint_A", 2.5)  # beyond the 2 A rating
            assert too_big.value.code == 3
            assert rig.history() == []
            response = client.write_register(0, 1, device_id=1)
            assert not response.isError()
            unmapped_write = client.write_register(40, 1, device_id=1)
            assert unmapped_write.isError() and unmapped_write.exception_code == 2
            unmapped = client.read_holding_registers(40, count=1, device_id=1)
            assert unmapped.isError() and unmapped.exception_code == 2
        finally:
            client.close()
    assert rig.last_setpoint_A == pytest.approx(1e-4)


def test_read_only_holding_register_refuses_writes(rig):
    m = RegisterMap.from_dict({"channels": {
        "current_setpoint_A": {"function": "holding", "address": 0, "type": "int16", "scale": 0.001, "access": "rw"},
        "heartbeat": {"function": "holding", "address": 1, "type": "uint16", "access": "r"},
    }})
    with ModbusEmulator(rig, m) as emu:
        client = tcp_client(emu)
        try:
            first = read_channel(client, m, "heartbeat")
            assert read_channel(client, m, "heartbeat") > first  # the device's counter moves
            response = client.write_register(1, 7, device_id=1)
            assert response.isError() and response.exception_code == 2
            assert rig.output_enabled  # a map without an enable switch means always on
        finally:
            client.close()


def test_half_of_a_32bit_register_is_refused(rig):
    m = load_register_map(MIXED_MAP)
    with ModbusEmulator(rig, m) as emu:
        client = tcp_client(emu)
        try:
            response = client.write_register(m["current_setpoint_A"].address, 0x3F80, device_id=1)
            assert response.isError() and response.exception_code == 2
            assert rig.history() == []
        finally:
            client.close()


# ---- Modbus faults ---------------------------------------------------------------------------------

def test_status_word_reports_output_and_device_failure(rig):
    m = load_register_map(INT_MAP)
    with ModbusEmulator(rig, m) as emu:
        client = tcp_client(emu)
        try:
            assert read_channel(client, m, "status") == 0
            write_channel(client, m, "output_enable", 1)
            rig.faults.set("stuck:force_N")  # the device cannot know its sensor is stuck
            assert read_channel(client, m, "status") == 1
        finally:
            client.close()
    assert rig.status_word() == 1
    rig.faults.set("exception")
    assert rig.status_word() == 3


@pytest.mark.parametrize("fault", ["exception:4", "garbage"])
def test_modbus_rtu_exception_and_garbage_faults(rig, fault):
    m = load_register_map(INT_MAP)
    with ModbusEmulator(rig, m, transport="rtu") as emu:
        client = rtu_client(emu, timeout=0.3)
        try:
            rig.faults.set(fault)
            with pytest.raises((ModbusException, ModbusFailure)) as failed:
                read_channel(client, m, "force_N")
            if fault.startswith("exception"):
                assert failed.value.code == 4
            rig.faults.clear()
            assert wait_for(lambda: _reads_ok(client, m))
        finally:
            client.close()


def _reads_ok(client, m) -> bool:
    try:
        return math.isfinite(read_channel(client, m, "force_N"))
    except (ModbusException, ModbusFailure):
        return False


def test_modbus_exception_fault_and_clear(rig):
    m = load_register_map(INT_MAP)
    rig.faults.set("exception:6")
    with ModbusEmulator(rig, m) as emu:
        client = tcp_client(emu)
        try:
            with pytest.raises(ModbusFailure) as busy:
                read_channel(client, m, "force_N")
            assert busy.value.code == 6
            with pytest.raises(ModbusFailure):
                write_channel(client, m, "current_setpoint_A", 1.0)
            assert rig.history() == []  # a failing device applies nothing
            rig.faults.clear("exception")
            assert math.isfinite(read_channel(client, m, "force_N"))
        finally:
            client.close()


@pytest.mark.realtime   # the recovered request must answer within a 0.3 s wall-clock timeout
@pytest.mark.parametrize("transport", ["tcp", "rtu"])
def test_modbus_silent_fault_no_answer_and_no_write(rig, transport):
    m = load_register_map(INT_MAP)
    with ModbusEmulator(rig, m, transport=transport) as emu:
        client = tcp_client(emu, timeout=0.3) if transport == "tcp" else rtu_client(emu, timeout=0.3)
        try:
            rig.faults.set("silent")
            with pytest.raises(ModbusException):
                write_channel(client, m, "current_setpoint_A", 1.0)
            assert rig.history() == []
            rig.faults.clear()
            client.close()
            assert client.connect()
            write_channel(client, m, "current_setpoint_A", 0.5)
            assert rig.last_setpoint_A == pytest.approx(0.5)
        finally:
            client.close()


def test_modbus_delay_fault_answers_late(rig):
    m = load_register_map(INT_MAP)
    rig.faults.set("delay:0.6")
    with ModbusEmulator(rig, m) as emu:
        impatient = tcp_client(emu, timeout=0.2)
        patient = tcp_client(emu, timeout=3.0)
        try:
            with pytest.raises(ModbusException):
                read_channel(impatient, m, "current_A")
            assert math.isfinite(read_channel(patient, m, "current_A"))  # the answer does come
        finally:
            impatient.close()
            patient.close()


@pytest.mark.realtime   # the recovered request must answer within a 0.3 s wall-clock timeout
def test_modbus_garbage_fault(rig):
    m = load_register_map(INT_MAP)
    with ModbusEmulator(rig, m, seed=3) as emu:
        client = tcp_client(emu, timeout=0.3)
        try:
            rig.faults.set("garbage")
            with pytest.raises((ModbusException, ModbusFailure)):
                read_channel(client, m, "current_A")
            rig.faults.clear("garbage")
            client.close()
            assert client.connect()
            assert math.isfinite(read_channel(client, m, "current_A"))
        finally:
            client.close()


def test_modbus_tcp_drop_fault_closes_connection_until_cleared(rig):
    m = load_register_map(INT_MAP)
    with ModbusEmulator(rig, m) as emu:
        client = tcp_client(emu, timeout=0.5)
        try:
            assert math.isfinite(read_channel(client, m, "current_A"))
            assert emu.connections == 1
            rig.faults.set("drop")
            assert wait_for(lambda: emu.connections == 0)  # cut at once, not at the next request
            # the client reports the cut as pymodbus's error or, when the reset reaches its read
            # first (a busy machine), as the socket's own: either way the request fails
            with pytest.raises((ModbusException, ConnectionError)):
                read_channel(client, m, "current_A")
            assert client.connect()  # the server still accepts, then drops on the first request
            with pytest.raises((ModbusException, ConnectionError)):
                read_channel(client, m, "current_A")
            assert rig.history() == []
            rig.faults.clear("drop")
            assert client.connect()
            assert math.isfinite(read_channel(client, m, "current_A"))
        finally:
            client.close()


def test_modbus_rtu_drop_fault_hangs_up_the_port_until_cleared(rig):
    m = load_register_map(INT_MAP)
    with ModbusEmulator(rig, m, transport="rtu") as emu:
        path = emu.address
        client = rtu_client(emu, timeout=0.5)
        try:
            assert math.isfinite(read_channel(client, m, "current_A"))
            rig.faults.set("drop")
            assert wait_for(lambda: not os.path.exists(path))  # unplugged
            with pytest.raises(ModbusException):
                read_channel(client, m, "current_A")
            client.close()
            rig.faults.clear()
            assert wait_for(lambda: os.path.exists(path))  # plugged back in, same path
            client = rtu_client(emu, timeout=0.5)
            assert math.isfinite(read_channel(client, m, "current_A"))
        finally:
            client.close()


@pytest.mark.parametrize("map_path", [INT_MAP, MIXED_MAP], ids=["int16_map", "mixed_units_map"])
def test_modbus_sensor_faults_stuck_nan_out_of_range(rig, map_path):
    m = load_register_map(map_path)
    with ModbusEmulator(rig, m) as emu:
        client = tcp_client(emu)
        try:
            write_channel(client, m, "output_enable", 1)
            rig.faults.set("stuck:current_A")
            frozen = read_channel(client, m, "current_A")
            write_channel(client, m, "current_setpoint_A", 1.5)
            assert wait_for(lambda: abs(rig.true_value("current_A") - 1.5) < 0.02)
            assert read_channel(client, m, "current_A") == frozen  # the sensor, not the plant, is stuck
            rig.faults.clear("stuck")
            assert read_channel(client, m, "current_A") == pytest.approx(rig.true_value("current_A"), abs=0.02)

            rig.faults.set("nan:force_N")
            force_ch = m["force_N"]
            words = client.read_input_registers(force_ch.address, count=force_ch.count, device_id=force_ch.unit_id).registers
            if force_ch.type == "float32":
                assert math.isnan(force_ch.decode(words))
            else:  # integers cannot hold NaN: the invalid marker (most negative raw value)
                assert words == [0x8000]
            rig.faults.clear()

            rig.faults.set("out_of_range:displacement_um=5000")
            reported = read_channel(client, m, "displacement_um")
            lo, hi = m["displacement_um"].physical_range
            # saturated if the type cannot hold it, one step short of the invalid marker (which means NaN)
            assert reported == pytest.approx(min(5000.0, hi - abs(m["displacement_um"].scale)), abs=1e-6)
            assert reported > 500
        finally:
            client.close()


# ---- SCPI serial amplifier -------------------------------------------------------------------------

def ask(port: serial.Serial, command: str) -> str:
    """Send a query and return its reply line ("" on timeout)."""
    port.write(command.encode() + b"\n")
    return port.readline().decode("ascii", "replace").strip()


def tell(port: serial.Serial, command: str) -> None:
    """Send a setting, then *OPC? so it has been applied when this returns."""
    port.write(command.encode() + b"\n")
    assert ask(port, "*OPC?") == "1"


@pytest.fixture
def amplifier(rig):
    with SerialAmplifierEmulator(rig) as emu:
        port = serial.Serial(emu.path, 115200, timeout=1.0)
        try:
            yield emu, port
        finally:
            port.close()


def test_serial_amplifier_protocol_and_plant(amplifier, rig):
    emu, port = amplifier
    assert ask(port, "*IDN?").startswith("GMA-FFC,")
    assert ask(port, "OUTP?") == "0"
    tell(port, "OUTP ON")
    tell(port, "sour:curr 1.25")
    assert ask(port, "OUTPut?") == "1"
    assert float(ask(port, "CURRent?")) == pytest.approx(1.25)
    assert wait_for(lambda: abs(float(ask(port, "MEAS:CURR?")) - 1.25) < 0.02)
    force = float(ask(port, "MEASure:FORCe?"))
    assert force == pytest.approx(rig.true_value("force_N"), rel=0.02, abs=1.0)
    assert float(ask(port, "meas:disp?")) > 1.0
    tell(port, "CURR 3")  # beyond the 2 A rating: refused, queued as an error
    tell(port, "VOLT 3")
    tell(port, "CURR abc")
    assert ask(port, "SYST:ERR?") == '-222,"Data out of range"'
    assert ask(port, "SYSTem:ERRor?") == '-113,"Undefined header"'
    assert ask(port, "SYST:ERR?") == '-104,"Data type error"'
    assert ask(port, "SYST:ERR?") == '0,"No error"'
    assert float(ask(port, "CURR?")) == pytest.approx(1.25)
    tell(port, "OUTP OFF")
    assert wait_for(lambda: abs(float(ask(port, "MEAS:CURR?"))) < 0.02)
    tell(port, "CURR 0")
    assert rig.last_setpoint_A == 0.0
    history = rig.history()
    assert [(c.kind, c.value) for c in history] == [
        ("output_enable", 1.0), ("setpoint", 1.25), ("output_enable", 0.0), ("setpoint", 0.0)]
    assert all(a.time_s <= b.time_s for a, b in zip(history, history[1:]))


def test_serial_link_faults(amplifier, rig):
    emu, port = amplifier
    port.timeout = 0.3
    rig.faults.set("silent")
    assert ask(port, "CURR?") == ""  # no answer
    seen = emu.lines_seen
    port.write(b"CURR 1\n")
    assert wait_for(lambda: emu.lines_seen == seen + 1)  # read by the device, and ignored
    rig.faults.clear()
    assert float(ask(port, "CURR?")) == 0.0  # the write during silence was not applied

    rig.faults.set("garbage")
    reply = port.write(b"*IDN?\n") and port.readline()
    assert reply.endswith(b"\n") and not reply.startswith(b"GMA")
    with pytest.raises(UnicodeDecodeError):
        reply.decode("ascii")
    rig.faults.clear()

    rig.faults.set("exception")
    port.timeout = 0.3
    assert ask(port, "MEAS:CURR?") == ""
    assert ask(port, "SYST:ERR?") == '-300,"Device-specific error"'
    rig.faults.clear()
    port.timeout = 1.0
    assert ask(port, "SYST:ERR?") == '0,"No error"'


def test_serial_delay_answer_eventually_arrives(amplifier, rig):
    emu, port = amplifier
    rig.faults.set("delay:0.4")
    port.timeout = 0.1
    assert ask(port, "*IDN?") == ""
    port.timeout = 2.0
    assert port.readline().startswith(b"GMA-FFC,")


def test_serial_sensor_faults(amplifier, rig):
    emu, port = amplifier
    tell(port, "OUTP ON")
    rig.faults.set("stuck:displacement_um")
    frozen = ask(port, "MEAS:DISP?")
    tell(port, "CURR 1.5")
    assert wait_for(lambda: rig.true_value("displacement_um") > 1.0)
    assert ask(port, "MEAS:DISP?") == frozen
    rig.faults.set("nan:force_N")
    assert ask(port, "MEAS:FORC?") == "nan"
    rig.faults.set("out_of_range:current_A=99")
    assert float(ask(port, "MEAS:CURR?")) == 99.0
    rig.faults.clear()
    assert float(ask(port, "MEAS:DISP?")) == pytest.approx(rig.true_value("displacement_um"), abs=0.5)
    assert ask(port, "MEAS:FORC?") != "nan"


def test_serial_drop_hangs_up_until_cleared(amplifier, rig):
    emu, port = amplifier
    assert ask(port, "OUTP?") == "0"
    rig.faults.set("drop")
    assert wait_for(lambda: not os.path.exists(emu.path))
    with pytest.raises(serial.SerialException):
        for _ in range(3):  # the hang-up shows on the next I/O
            ask(port, "OUTP?")
    port.close()
    rig.faults.clear()
    assert wait_for(lambda: os.path.exists(emu.path))
    port2 = serial.Serial(emu.path, 115200, timeout=1.0)
    try:
        assert ask(port2, "OUTP?") == "0"
    finally:
        port2.close()


def test_emulators_stop_cleanly(rig):
    m = load_register_map(INT_MAP)
    emu = ModbusEmulator(rig, m, transport="rtu")
    path = emu.start()
    threads = {emu._thread, emu._relay._thread}
    emu.stop()
    assert not any(t.is_alive() for t in threads)
    assert not os.path.exists(path)
    tcp = ModbusEmulator(rig, m)
    host, port = tcp.start()
    tcp.stop()
    client = ModbusTcpClient(host, port=port, timeout=0.3, retries=0)
    assert not client.connect()  # nobody listens any more
    amp = SerialAmplifierEmulator(rig)
    amp_path = amp.start()
    amp_thread = amp._thread
    amp.stop()
    assert not amp_thread.is_alive() and not os.path.exists(amp_path)


# ---- rig: real-time stepping, faults, control channel -----------------------------------------------

class FakeClock:
    def __init__(self):
        self.now = 100.0

    def __call__(self):
        return self.now


class CountingPlant(StandInPlant):
    def __init__(self):
        super().__init__()
        self.drives: list[float] = []

    def step(self, current_cmd_A, dt_s):
        self.drives.append(current_cmd_A)
        super().step(current_cmd_A, dt_s)


def test_rig_steps_wall_clock_time_in_dt_chunks_with_bounded_catch_up():
    clock, plant = FakeClock(), CountingPlant()
    rig = EmulatedRig(plant, dt_s=1e-3, max_catch_up_s=0.05, clock=clock)
    clock.now += 0.0105
    rig.read("current_A")
    assert plant.drives == [0.0] * 10  # output disabled: 0 A, setpoint or not
    rig.set_current(1.0)
    rig.set_output(True)
    clock.now += 0.003
    rig.advance()
    assert plant.drives[10:] == [1.0] * 3
    clock.now += 10.0  # a long idle gap: at most max_catch_up_s is simulated
    rig.advance()
    assert len(plant.drives) == 13 + 50
    assert rig.skipped_s == pytest.approx(10.0 + 0.0005 - 0.05, abs=2e-3)
    with pytest.raises(InputError, match="outside"):
        rig.set_current(float("nan"))
    assert rig.last_setpoint_A == 1.0


def test_encode_sensor_nan_and_saturation_on_integer_registers():
    m = RegisterMap.from_dict({"channels": {
        "a": {"function": "input", "address": 0, "type": "int16", "scale": 0.1},
        "b": {"function": "input", "address": 1, "type": "uint16"},
        "c": {"function": "input", "address": 2, "type": "float32"},
    }})
    assert encode_sensor(m["a"], math.nan) == [0x8000]
    assert encode_sensor(m["b"], math.nan) == [0xFFFF]
    assert math.isnan(m["c"].decode(encode_sensor(m["c"], math.nan)))
    assert encode_sensor(m["a"], 1e9) == [0x7FFF] and encode_sensor(m["a"], -1e9) == [0x8001]
    assert encode_sensor(m["b"], 1e9) == [0xFFFE] and encode_sensor(m["b"], -5) == [0]
    assert m["c"].decode(encode_sensor(m["c"], 1e50)) == pytest.approx(3.4028234663852886e38)
    assert m["a"].decode(encode_sensor(m["a"], 12.3)) == pytest.approx(12.3)


def test_fault_specs():
    assert str(parse_fault("delay:0.25")) == "delay:0.25"
    assert parse_fault("out-of-range:force_N=-7").value == -7.0
    assert parse_fault("exception").value == 4
    for bad in ("fire", "delay", "delay:-1", "nan", "nan:temperature", "exception:99", "silent:1",
                "out_of_range:force_N=x"):
        with pytest.raises(FaultSpecError):
            parse_fault(bad)


def test_control_socket_sets_and_clears_faults(rig):
    with ControlServer(rig) as control:
        assert send_control(control.path, "fault nan:force_N") == {"ok": True, "set": "nan:force_N"}
        assert math.isnan(rig.read("force_N"))
        status = send_control(control.path, "status")
        assert status["faults"] == ["nan:force_N"] and status["output_enabled"] is False
        assert send_control(control.path, "clear")["cleared"] == ["nan:force_N"]
        assert math.isfinite(rig.read("force_N"))
        before = rig.true_value("force_N")
        assert send_control(control.path, "load 50")["ok"]
        assert wait_for(lambda: rig.true_value("force_N") > before + 400)  # 50 kg * g on the load cell
        assert send_control(control.path, "status")["stress_MPa"] < -20  # about -24 MPa on the 7 mm rod
        reply = send_control(control.path, "fault nonsense")
        assert reply["ok"] is False and "unknown kind" in reply["error"]
    assert execute(rig, "reboot")["ok"] is False
    assert not os.path.exists(control.path)


# ---- the command-line entry point --------------------------------------------------------------------

def _start_cli(*args: str) -> tuple[subprocess.Popen, dict[str, str]]:
    proc = subprocess.Popen([sys.executable, "-m", "hil_sim.emulators", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    info: dict[str, str] = {}
    end = time.monotonic() + 30
    while "control" not in info and time.monotonic() < end:
        line = proc.stdout.readline()
        if not line:
            break
        key, _, value = line.partition(": ")
        info[key.strip()] = value.strip()
    return proc, info


def test_cli_modbus_tcp_with_start_fault_and_control_channel():
    proc, info = _start_cli("modbus-tcp", "--port", "0", "--fault", "exception:6", "--duration", "60")
    try:
        assert "connect" in info and "control" in info, proc.stderr.read() if proc.poll() is not None else info
        host, port = info["connect"].rsplit(":", 1)
        m = load_register_map(INT_MAP)
        client = ModbusTcpClient(host, port=int(port), timeout=1.0, retries=0)
        assert client.connect()
        try:
            with pytest.raises(ModbusFailure) as busy:
                read_channel(client, m, "current_A")
            assert busy.value.code == 6
            assert send_control(info["control"], "clear exception")["ok"]
            write_channel(client, m, "current_setpoint_A", 0.75)
            status = send_control(info["control"], "status")
            assert status["last_setpoint_A"] == pytest.approx(0.75)
        finally:
            client.close()
        proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=10)
        assert proc.returncode == 0 and "stopped" in out
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def test_cli_serial_amplifier_prints_its_port_and_stops_on_sigint():
    proc, info = _start_cli("serial", "--fault", "nan:force_N", "--load-mass", "20", "--duration", "60")
    try:
        assert "connect" in info and "control" in info, proc.stderr.read() if proc.poll() is not None else info
        with serial.Serial(info["connect"], 115200, timeout=2.0) as port:
            assert ask(port, "MEAS:FORC?") == "nan"
            assert send_control(info["control"], "clear")["cleared"] == ["nan:force_N"]
            assert float(ask(port, "MEAS:FORC?")) > 500  # preload plus 20 kg on the load cell
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=10)
        assert proc.returncode == 0 and "stopped" in out and "Traceback" not in err
        assert not os.path.exists(info["connect"]) and not os.path.exists(info["control"])
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(5)


def test_cli_help_teaches_faults_and_commands():
    for kind, expected in (("modbus-tcp", "stuck:CHANNEL"), ("serial", "MEASure:FORCe?")):
        result = subprocess.run([sys.executable, "-m", "hil_sim.emulators", kind, "--help"], capture_output=True,
                                text=True, timeout=30)
        assert result.returncode == 0 and expected in result.stdout and "--fault" in result.stdout


@pytest.mark.parametrize("args, message", [
    (["serial", "--fault", "melt"], "unknown kind 'melt'"),
    (["modbus-tcp", "--port", "0", "--map", "/nonexistent/map.yaml"], "cannot read"),
])
def test_cli_bad_input_exits_2_with_one_line(args, message):
    result = subprocess.run([sys.executable, "-m", "hil_sim.emulators", *args], capture_output=True,
                            text=True, timeout=30)
    assert result.returncode == 2
    assert message in result.stderr and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_the_emulator_commands_sensors_are_noisy_like_a_real_rigs_unless_asked_not_to():
    """Its load cell read bit-identical while the load held still, so the shipped Modbus config
    (sensor.stale_ticks 250) faulted 'load-cell reading stuck' after any 1 s hold (a new user's
    sweep, 2026-11-30). The command's plant has the sensors' noise; `--quiet-sensors` removes it."""
    import subprocess
    import sys

    from pymodbus.client import ModbusTcpClient

    from hil_sim.emulators.plantsource import make_plant

    assert not make_plant().cfg.noise.enabled                    # in-process rigs keep their own choice
    for quiet, varies in ((False, True), (True, False)):
        emu = subprocess.Popen([sys.executable, "-m", "hil_sim.emulators", "modbus-tcp", "--port", "0", "--duration", "20",
                                "--load-mass", "20"] + (["--quiet-sensors"] if quiet else []),
                               stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        try:
            assert emu.stdout is not None
            host, port = next(line for line in emu.stdout if line.startswith("connect:")).split()[1].rsplit(":", 1)
            client = ModbusTcpClient(host, port=int(port), timeout=2)
            assert client.connect()
            forces = {tuple(client.read_input_registers(1, count=1).registers) for _ in range(40)}
            client.close()
            assert (len(forces) > 1) == varies, forces          # the load held still all along
        finally:
            emu.terminate()
            emu.wait(10)


def test_a_port_in_use_is_bad_input_and_the_free_port_it_advises_serves(rig):
    """Two emulators on 5020 (the config's port, the docs' example): the second said "cannot listen
    on 127.0.0.1:5020: Address already in use", exit 1 as for a fault. It is the user's to fix (exit
    2) and names --port 0; so started, it serves on a free port."""
    import socket

    m = load_register_map(DEVICE_CONFIGS / "amplifier_int16.yaml")
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(InputError, match=r"it is in use .* give --port 0 for a free port") as err:
            ModbusEmulator(rig, m, port=port).start()
        assert err.value.exit_code == 2
        with ModbusEmulator(rig, m, port=0) as emu:
            host, free = emu.address
            assert free not in (0, port)
            client = ModbusTcpClient(host, port=free)
            assert client.connect()
            client.close()
