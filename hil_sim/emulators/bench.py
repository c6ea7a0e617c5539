"""Round-trip figures of the emulators: `python -m hil_sim.emulators.bench [--n 500]`.

For each transport, a real client reads the three sensors and writes the setpoint, N times; the
baseline is the same work done in-process on the rig (no protocol), in the same process, so the
ratio shows what the protocol stack costs. A controller at 1 kHz needs a cycle well under 1 ms.
"""

from __future__ import annotations

import argparse
import statistics
import time

import serial
from pymodbus.client import ModbusSerialClient, ModbusTcpClient

from gma_ffc.registers import load_register_map

from . import DEFAULT_MAP
from .modbus import ModbusEmulator
from .plantsource import make_plant
from .rig import EmulatedRig
from .scpi import SerialAmplifierEmulator

SENSORS = ("current_A", "force_N", "displacement_um")


def _crc16(data: bytes) -> bytes:
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc.to_bytes(2, "little")


def _rtu_frame(unit: int, function: int, address: int, count: int, words: list[int] | None = None):
    """An RTU request (FC4 read or FC16 write) and the length of its reply."""
    body = bytes([unit, function]) + address.to_bytes(2, "big") + count.to_bytes(2, "big")
    if function == 16:
        body += bytes([2 * count]) + b"".join(w.to_bytes(2, "big") for w in words or ())
        return body + _crc16(body), 8
    return body + _crc16(body), 5 + 2 * count


def _time(cycle, n: int) -> list[float]:
    cycle(0)  # first call outside the timing (connection set-up, caches)
    out = []
    for i in range(n):
        t0 = time.perf_counter()
        cycle(i)
        out.append(time.perf_counter() - t0)
    return out


def _summary(name: str, samples: list[float], baseline_s: float | None) -> str:
    med = statistics.median(samples)
    p99 = sorted(samples)[int(0.99 * (len(samples) - 1))]
    ratio = f"{med / baseline_s:8.0f}x baseline" if baseline_s else ""
    return f"{name:<22} median {med * 1e3:7.3f} ms   p99 {p99 * 1e3:7.3f} ms   {ratio}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m hil_sim.emulators.bench", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--n", type=int, default=500, help="cycles per transport (default 500)")
    args = parser.parse_args(argv)
    m = load_register_map(DEFAULT_MAP)
    rig = EmulatedRig(make_plant())
    rig.set_output(True)

    def in_process(i: int) -> None:
        rig.set_current(0.5 + 0.001 * (i % 100))
        for name in SENSORS:
            rig.read(name)

    base = _time(in_process, args.n)
    baseline_s = statistics.median(base)
    print(f"cycle = write setpoint + read current, force, displacement; n = {args.n}")
    print(_summary("in-process (baseline)", base, None))
    plan = m.read_plan(SENSORS)
    sp = m["current_setpoint_A"]

    def modbus_cycle(client):
        def cycle(i: int) -> None:
            client.write_registers(sp.address, sp.encode(0.5 + 0.001 * (i % 100)), device_id=sp.unit_id)
            for block in plan:
                r = client.read_input_registers(block.address, count=block.count, device_id=block.unit_id)
                block.decode(r.registers)
        return cycle

    with ModbusEmulator(rig, m, transport="tcp") as emu:
        host, port_no = emu.host_port
        tcp = ModbusTcpClient(host, port=port_no, timeout=2, retries=0)
        tcp.connect()
        print(_summary("modbus tcp", _time(modbus_cycle(tcp), args.n), baseline_s))
        tcp.close()
    with ModbusEmulator(rig, m, transport="rtu") as emu:
        rtu = ModbusSerialClient(emu.serial_path, baudrate=115200, timeout=2, retries=0)
        rtu.connect()
        print(_summary("modbus rtu (pty)", _time(modbus_cycle(rtu), args.n), baseline_s))
        rtu.close()
        # The same frames by hand with pyserial: what the emulator itself costs, without pymodbus'
        # sync serial client (which waits for inter-frame silence in 1 ms sleeps).
        frames = [_rtu_frame(sp.unit_id, 16, sp.address, sp.count, sp.encode(0.5))]
        frames += [_rtu_frame(b.unit_id, 4, b.address, b.count) for b in plan]
        with serial.Serial(emu.serial_path, 115200, timeout=2) as port:
            def raw_cycle(i: int) -> None:
                for frame, reply_len in frames:
                    port.write(frame)
                    if len(port.read(reply_len)) != reply_len:
                        raise RuntimeError("short RTU reply")
            print(_summary("modbus rtu raw pyserial", _time(raw_cycle, args.n), baseline_s))
    with SerialAmplifierEmulator(rig) as amp:
        port = serial.Serial(amp.path, 115200, timeout=2)

        def scpi_cycle(i: int) -> None:
            port.write(f"CURR {0.5 + 0.001 * (i % 100):.4f}\n".encode())
            for query in (b"MEAS:CURR?\n", b"MEAS:FORC?\n", b"MEAS:DISP?\n"):
                port.write(query)
                float(port.readline())

        print(_summary("scpi serial (pty)", _time(scpi_cycle, args.n), baseline_s))
        port.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
