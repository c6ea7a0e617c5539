"""The controller: fixed-rate inverse-SDPI feedforward with safety and telemetry (issues 4, 34).

    from gma_ffc.control.config import load_config
    from gma_ffc.control.manager import ControllerManager

    cfg = load_config("config/sim.yaml")         # ConfigError naming the key on any mistake
    ctrl = ControllerManager(cfg)                # builds model, driver, law, telemetry
    summary = ctrl.run(stop_event, duration_s)   # blocking; the safe current on every way out
    ctrl.status()                                # thread-safe snapshot; ctrl.request_stop(reason)
    ctrl.reload(load_config(path))               # bumpless; the old config is kept on error

The parts, named after ros2_control's (docs/ARCHITECTURE.md has the table):
`manager` (the controller manager: the fixed-rate loop and the fault-table interpreter),
`law` (the controller: `update()`, its learner, its lifecycle), `hardware` (the driver
supervisor: resource manager and hardware lifecycle), `recorder` and `state_broadcaster`
(broadcasters: telemetry and status, fed a `tick.Tick` each tick), `model_monitor` (a broadcaster:
the model's prediction beside the command and the model-fit monitor), `builder` (config to parts),
`setup` (what a reload swaps), `envelope` (the model's drive and stress ranges and their
policies), `safety` (limits, sensor plausibility, the fault table), `current_tracking` (the
measured coil current against the command), `faults` (fault bookkeeping),
`watchdog`, `realtime` (SCHED_FIFO, GC, GIL interval), `learned_file`, `learning`, `config`,
`scheduler`, `reference`, `telemetry` (the recording's writer thread).
"""
