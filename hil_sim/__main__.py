"""`python -m hil_sim record ...`: write recordings from the simulated GMA (see docs/hil_sim.md)."""

from __future__ import annotations

import argparse
import sys
from typing import Sequence

from gma_ffc.console import dispatch
from gma_ffc.errors import InputError
from gma_ffc.progress import Progress

DESCRIPTION = """\
Simulated giant magnetostrictive actuator (Jiles-Atherton + stress, phi 7 mm Terfenol-D rod,
-11.3 MPa preload, up to 50 kg load) for testing gma-ffc without hardware.

  record    write CSV recordings (docs/recordings.md format) for one experiment kind

The same actuator behind the protocols real amplifiers speak (Modbus TCP/RTU, serial), for
`gma-ffc run` against it: `python -m hil_sim.emulators --help`.
"""

RECORD_EPILOG = """\
kinds (one CSV per experiment in DIR, plus DIR/manifest.yaml):
  identification  3 Hz sine 0-3 A, 4 periods, at -11.3 -13.2 -15.2 -19.1 -21.5 -24 MPa, 2 kHz
                  (--minor-loops adds one period each at 80, 60, 40 % amplitude)
  multifreq       sines 0-3 A at 1 3 10 30 50 100 200 Hz, unloaded (-11.3 MPa), 10 kHz
  long            3 Hz sine for 150 s then 0 A for 90 s: the coil heats and cools, 1 kHz
  steps           current steps 0.5 1.5 2.5 1.0 2.0 0 A held 12 s each, 1 kHz
  stress_change   3 Hz sine while the load goes 0 -> 15.3 -> 30.6 -> 49.8 -> 0 kg, 2 kHz
  rising          sines 0-3 A whose amplitude grows from 0 and decays back (3 Hz for 8 s, 20 Hz
                  for 4 s, 60 Hz for 3 s), at -13.2 and -19.1 MPa, on a rod cycled before, 2 kHz

effects (off unless --effects or the config switch them on; 'none' = all off, 'all' = all on):
  eddy       eddy currents: the rod field lags the coil (loop widens with frequency)
  dynamics   rod stiffness and load mass: resonance sqrt(k/m)/2pi, moves with the load
  thermal    Joule heating, thermal time constant ~60 s, slow displacement drift
  creep      slow relaxation after drive changes
  delay      transport delay on the displacement measurement
  amplifier  first-order current loop (measured current lags the command)
  noise      sensor noise and quantisation (displacement, current, load cell, temperature)

The recordings never say which effects were on; DIR/manifest.yaml does.
The effects are the actuator's: one actuator has the same ones in every run. Give the
identification runs the diagnosis runs' --effects (or --config) to simulate one actuator; loops
without an effect the later runs show are an actuator that changed since it was identified.

examples:
  python -m hil_sim record --kind identification --out rec/ident --effects noise
  python -m hil_sim record --kind long --out rec/long --effects thermal,noise --seed 7
  python -m hil_sim record --kind rising --out rec/rising --effects eddy,noise
  python -m hil_sim record --kind steps --out rec/steps --config hil_sim/configs/realistic.yaml
"""


class _Parser(argparse.ArgumentParser):
    """Bad usage is one line and exit 2, like gma-ffc."""

    def error(self, message: str) -> None:  # type: ignore[override]
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def parse_effects(text: str | None) -> list[str] | None:
    from .plant import EFFECTS

    if text is None:
        return None
    names = [n.strip() for n in text.split(",") if n.strip()]
    if names == ["none"]:
        return []
    if names == ["all"]:
        return list(EFFECTS)
    unknown = [n for n in names if n not in EFFECTS]
    if unknown:
        raise InputError(f"--effects: unknown effect {', '.join(unknown)}; "
                         f"choose from {', '.join(EFFECTS)} (or 'none' / 'all')")
    return names


def build_parser() -> argparse.ArgumentParser:
    from .record import KINDS

    parser = _Parser(prog="python -m hil_sim", description=DESCRIPTION,
                     formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    sub.required = True
    rec = sub.add_parser("record", help="write recordings from the simulated actuator",
                         description="Write CSV recordings of one experiment kind from the simulated GMA.",
                         epilog=RECORD_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    rec.add_argument("--kind", required=True, choices=list(KINDS), help="which experiment (see below)")
    rec.add_argument("--out", required=True, metavar="DIR", help="directory for the CSV files and manifest.yaml")
    rec.add_argument("--config", metavar="PLANT.yaml",
                     help="plant parameters (default: built-in, see hil_sim/configs/default.yaml)")
    rec.add_argument("--seed", type=int, default=0, help="noise seed; same seed, same files (default 0)")
    rec.add_argument("--effects", metavar="LIST",
                     help="comma list of effects to switch on, overriding the config (e.g. thermal,noise)")
    rec.add_argument("--minor-loops", action="store_true",
                     help="identification: add shrinking minor loops after the full ones")
    rec.set_defaults(func=cmd_record)
    return parser


def cmd_record(args: argparse.Namespace) -> int:
    from .plant import PlantConfig
    from .record import experiments, write_recordings

    cfg = PlantConfig.from_yaml(args.config) if args.config else PlantConfig()
    effects = parse_effects(args.effects)
    options = {"minor_loops": True} if args.minor_loops else {}
    if args.seed < 0:       # numpy's generators take seeds from 0; a negative one overflowed with a warning
        raise InputError(f"--seed must be a whole number from 0 up, got {args.seed}")
    if args.minor_loops and args.kind != "identification":
        raise InputError("--minor-loops only applies to --kind identification")
    count = len(experiments(args.kind, cfg, **options))
    with Progress(f"recording {args.kind}", total=count) as progress:
        paths = write_recordings(args.kind, args.out, cfg, seed=args.seed, effects=effects,
                                 progress=progress, **options)
    print(f"wrote {len(paths)} recording(s) and manifest.yaml to {args.out}")
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return dispatch(f"hil_sim {args.command}", lambda: args.func(args))


if __name__ == "__main__":
    sys.exit(main())
