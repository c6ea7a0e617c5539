"""`gma-ffc run`: the controller in the foreground, as systemd runs it (Type=notify)."""

from __future__ import annotations

import argparse
import logging
import math
import sys
from pathlib import Path

from ..errors import ConfigError


def positive_seconds(text: str) -> float:
    """argparse type: a finite duration > 0 (bad ones become one line and exit 2)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number of seconds") from None
    if not math.isfinite(value) or value <= 0:
        raise argparse.ArgumentTypeError(f"{text!r} must be a finite number of seconds > 0")
    return value


def add_runtime_dir(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runtime-dir", metavar="DIR",
                   help="private directory for the control socket, pid file and log (default: "
                        "$GMA_FFC_RUNTIME_DIR, $RUNTIME_DIRECTORY, /run/gma-ffc if it is yours "
                        "(the systemd service's), $XDG_RUNTIME_DIR/gma-ffc, /run/gma-ffc for root, "
                        "else /tmp/gma-ffc-UID)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run", help="run the controller in the foreground (what the systemd unit runs)",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="examples:\n"
               "  gma-ffc run --config config/sim.yaml --duration 10 --stats-json stats.json\n"
               "  gma-ffc run --config rig.yaml --learned learned.yaml   # learning feedforward, kept across runs",
        description="Run the controller in the foreground until --duration ends, SIGTERM/SIGINT "
                    "or 'gma-ffc stop'. Speaks systemd's notify protocol when NOTIFY_SOCKET is "
                    "set (READY, STATUS, WATCHDOG while the loop progresses, STOPPING). SIGHUP "
                    "re-reads the config and model; a bad one is refused and the old keeps "
                    "running. 'gma-ffc status' and 'gma-ffc stop' reach it over its control socket.")
    p.add_argument("--config", required=True, metavar="CFG.yaml", help="controller configuration")
    p.add_argument("--duration", type=positive_seconds, metavar="S",
                   help="stop after S seconds (default: run until stopped)")
    p.add_argument("--stats-json", metavar="F", help="write the final status to F (atomically)")
    p.add_argument("--learned", metavar="FILE",
                   help="learning feedforward's correction: start from FILE if it exists (learned "
                        "for this model, period and rate) and save it back there at stop; needs "
                        "'learning: {kind: repetitive}' in the config (overrides learning.file)")
    add_runtime_dir(p)
    p.add_argument("--no-socket", action="store_true",
                   help="do not serve the control socket (several scripted runs side by side)")
    p.add_argument("--log-level", default="INFO", type=str.upper,
                   choices=("DEBUG", "INFO", "WARNING", "ERROR"), help="default INFO (any case)")
    p.set_defaults(func=_run)


def _run(args: argparse.Namespace) -> int:
    from ..control.config import check_config_file
    from ..service.paths import runtime_paths
    from ..service.runner import Service

    config = Path(args.config)
    check_config_file(config)
    logging.basicConfig(stream=sys.stderr, level=getattr(logging, args.log_level),
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    runtime = None if args.no_socket else runtime_paths(args.runtime_dir)
    loader = _config_loader(args.learned, needs_real_clock=args.duration is None)
    service = Service(config, duration_s=args.duration, stats_json=args.stats_json, runtime=runtime,
                      load_config=loader)
    code = service.run()
    logging.getLogger("gma_ffc.service").info("stopped: %s", service.status()["service"]["stop_reason"])
    return code


def _config_loader(learned: str | None, *, needs_real_clock: bool):
    """The Service's config loader: the file as written, with --learned applied, and without
    --duration a simulated clock refused (at start and on every reload)."""
    from ..control.config import load_config

    def load(config_path: Path):
        cfg = load_config(config_path)
        if needs_real_clock:
            _refuse_a_run_without_end(config_path, cfg.clock)
        return cfg if learned is None else _with_learned_file(cfg, config_path, learned)

    return load


def _refuse_a_run_without_end(config: Path, clock: str) -> None:
    """A simulated clock never sleeps: without --duration the run would go as fast as the CPU allows
    until stopped (65,000 ticks a second under a status claiming 1000 Hz, 35 GB of telemetry an hour).
    Tests that drive the clock themselves build the Service directly, not through this command."""
    if clock == "simulated":
        raise ConfigError(f"{config}: config key 'clock' is 'simulated', which runs as fast as the CPU allows "
                          "and never stops by itself: give --duration S, or set clock: real to run at rate_hz "
                          "until 'gma-ffc stop'")


def _with_learned_file(cfg, config_path: Path, path: str):
    """`cfg` with learning.file pointed at `path` (the --learned option)."""
    import dataclasses

    learned = str(Path(path).expanduser().resolve())
    if not cfg.learning.enabled:
        raise ConfigError(f"--learned {path}: learning is off in {config_path}; add "
                          f"'learning: {{kind: repetitive}}' to use a learned correction")
    cfg.learning = dataclasses.replace(cfg.learning, file=learned)
    cfg.learned_setting = "--learned"        # what a refusal of that file tells the user to change
    if cfg.output_dirs:      # named on the command line: its folder is named for output too
        cfg.output_dirs = (*cfg.output_dirs, str(Path(learned).parent))
    return cfg
