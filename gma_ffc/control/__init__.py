"""The controller: fixed-rate inverse-SDPI feedforward with safety and telemetry (issue 4).

    from gma_ffc.control.config import load_config
    from gma_ffc.control.controller import Controller

    cfg = load_config("config/sim.yaml")        # ConfigError naming the key on any mistake
    ctrl = Controller(cfg)                       # builds model, driver, reference, telemetry
    summary = ctrl.run(stop_event, duration_s)   # blocking; the safe current on every way out
    ctrl.status()                                # thread-safe snapshot; ctrl.request_stop(reason)
    ctrl.reload(load_config(path))               # bumpless; the old config is kept on error

Modules: `config` + `schema` (validation), `scheduler` (clocks, absolute deadlines, timing
statistics), `reference` (sine, triangle, multi-sine, playback), `safety` (limits, sensor
checks, which faults ramp and which jump to the safe current), `telemetry` (ring buffer and
writer thread), `controller` (the loop), `sil` (software-in-the-loop helpers).
"""
