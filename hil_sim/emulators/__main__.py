"""`python -m hil_sim.emulators KIND ...`: run one emulated device until Ctrl-C / SIGTERM."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import threading

from gma_ffc.console import dispatch
from gma_ffc.errors import InputError
from gma_ffc.registers import load_register_map

from . import DEFAULT_MAP, DEVICE_CONFIGS
from .control import ControlServer, send_control
from .faults import __doc__ as FAULTS_DOC
from .faults import parse_fault
from .modbus import ModbusEmulator
from .plantsource import make_plant
from .rig import EmulatedRig
from .scpi import SerialAmplifierEmulator
from .scpi import __doc__ as SCPI_DOC

DESCRIPTION = """\
Emulated rig devices for hardware-in-the-loop tests: the simulated GMA behind the protocols real
hardware speaks. Each device prints where to connect and a control socket for faults, then runs
until Ctrl-C (or --duration).

  modbus-tcp   Modbus TCP server (pymodbus), register map from YAML
  modbus-rtu   Modbus RTU device on a pseudo-terminal (open the printed path as a serial port)
  serial       SCPI-style current amplifier on a pseudo-terminal
  control      send a command to a running emulator's control socket

Examples:
  python -m hil_sim.emulators modbus-tcp --port 5020
  python -m hil_sim.emulators modbus-rtu --map {configs}/multi_unit_mixed.yaml
  python -m hil_sim.emulators serial --fault delay:0.2
  python -m hil_sim.emulators control /tmp/gma-hil-ctl-XXXX/control.sock fault nan:force_N
""".format(configs=DEVICE_CONFIGS)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m hil_sim.emulators", description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    sub = parser.add_subparsers(dest="kind", required=True, metavar="KIND")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--plant-config", metavar="YAML", help="hil_sim plant config (default: the plant's defaults)")
        p.add_argument("--seed", type=int, default=0, help="plant noise and garbage seed (default 0)")
        p.add_argument("--quiet-sensors", action="store_true",
                       help="without --plant-config: sensors without noise (by default they have a real one's: a "
                            "load cell read bit-identical for a second is a stuck one, and the shipped configs "
                            "fault on it)")
        p.add_argument("--fault", action="append", default=[], metavar="KIND[:ARG]",
                       help="start with this fault active (repeatable; see the fault list below)")
        p.add_argument("--load-mass", type=float, metavar="KG", help="load mass on the rod at start (default: the plant config's)")
        p.add_argument("--max-current", type=float, default=2.0, metavar="A",
                       help="amplifier rating; larger setpoints are refused (default 2 A)")
        p.add_argument("--dt", type=float, default=1e-3, metavar="S", help="plant step (default 1 ms)")
        p.add_argument("--control", metavar="PATH", help="control socket path (default: a fresh temp path)")
        p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: run until stopped)")

    def modbus_common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--map", default=str(DEFAULT_MAP), metavar="YAML",
                       help=f"register map (default {DEFAULT_MAP.name}; examples in {DEVICE_CONFIGS})")
        p.add_argument("--latency-ms", metavar="LO-HI", type=_latency_ms,
                       help="hold every request a random LO-HI ms (uniform, seeded by --seed) before it takes "
                            "effect, e.g. 1-2: the timing jitter of a busy network (default: none)")

    epilog = FAULTS_DOC
    tcp = sub.add_parser("modbus-tcp", help="Modbus TCP server", epilog=epilog,
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    tcp.add_argument("--host", default="127.0.0.1", help="address to bind (default 127.0.0.1)")
    tcp.add_argument("--port", type=int, default=5020, help="TCP port, 0 = any free port (default 5020)")
    modbus_common(tcp)
    common(tcp)
    rtu = sub.add_parser("modbus-rtu", help="Modbus RTU device on a pty", epilog=epilog,
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    rtu.add_argument("--baudrate", type=int, default=115200, help="nominal baud rate (default 115200)")
    modbus_common(rtu)
    common(rtu)
    ser = sub.add_parser("serial", help="SCPI-style amplifier on a pty", epilog=SCPI_DOC + "\n" + epilog,
                         formatter_class=argparse.RawDescriptionHelpFormatter)
    common(ser)
    ctl = sub.add_parser("control", help="talk to a running emulator",
                         description="Commands: fault KIND[:ARG] | clear [KIND[:CHANNEL]] | load KG | status")
    ctl.add_argument("socket", help="the control socket path the emulator printed")
    ctl.add_argument("command", nargs="+", help="fault SPEC | clear [SPEC] | load KG | status")
    return parser


def _latency_ms(text: str) -> tuple[float, float]:
    lo, sep, hi = text.partition("-")
    try:
        pair = (float(lo) * 1e-3, float(hi if sep else lo) * 1e-3)
    except ValueError:
        raise argparse.ArgumentTypeError(f"'{text}': give LO-HI in milliseconds, e.g. 1-2") from None
    if not 0.0 <= pair[0] <= pair[1] <= 1.0:
        raise argparse.ArgumentTypeError(f"'{text}': need 0 <= LO <= HI <= 1000 ms")
    return pair


def run(args: argparse.Namespace) -> int:
    if args.kind == "control":
        reply = send_control(args.socket, " ".join(args.command))
        print(json.dumps(reply, indent=2))
        return 0 if reply.get("ok") else 2
    if args.duration is not None and not args.duration > 0:
        raise InputError(f"--duration {args.duration}: give a positive number of seconds (or leave it out)")
    faults = [parse_fault(spec) for spec in args.fault]  # bad specs fail before anything starts
    register_map = load_register_map(args.map) if args.kind != "serial" else None
    rig = EmulatedRig(make_plant(args.plant_config, seed=args.seed, sensor_noise=not args.quiet_sensors),
                      dt_s=args.dt, max_current_A=args.max_current)
    if args.load_mass is not None:
        rig.set_load_mass(args.load_mass)
    for fault in faults:
        rig.faults.set(fault)
    device: SerialAmplifierEmulator | ModbusEmulator
    if register_map is None:
        device = SerialAmplifierEmulator(rig, seed=args.seed)
    else:
        device = ModbusEmulator(rig, register_map, transport="tcp" if args.kind == "modbus-tcp" else "rtu",
                                host=getattr(args, "host", "127.0.0.1"), port=getattr(args, "port", 0),
                                baudrate=getattr(args, "baudrate", 115200), seed=args.seed,
                                latency_s=args.latency_ms)
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    control = ControlServer(rig, args.control)
    with device, control:
        address = device.address
        where = f"{address[0]}:{address[1]}" if isinstance(address, tuple) else address
        print(f"{args.kind} emulator ready", flush=True)
        print(f"connect: {where}", flush=True)
        if register_map is not None:
            print(f"register map: {args.map} (units {', '.join(map(str, register_map.unit_ids))})", flush=True)
        print(f"control: {control.path}", flush=True)
        if faults:
            print(f"faults: {', '.join(map(str, faults))}", flush=True)
        if getattr(args, "latency_ms", None):
            print(f"latency: {1e3 * args.latency_ms[0]:g}-{1e3 * args.latency_ms[1]:g} ms on every request", flush=True)
        stop.wait(args.duration)
    print("stopped", flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return dispatch(f"hil_sim.emulators {args.kind}", lambda: run(args))


if __name__ == "__main__":
    sys.exit(main())
