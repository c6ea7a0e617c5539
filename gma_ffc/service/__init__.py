"""The service around the controller: `gma-ffc run` (foreground, systemd Type=notify),
`start`/`stop`/`status` over an owner-only Unix socket, SIGHUP reload.

Use:
    gma-ffc run --config CFG.yaml [--duration S] [--stats-json F]   # foreground (systemd runs this)
    gma-ffc start --config CFG.yaml     # background; returns when READY, or fails with the reason
    gma-ffc status [--json]             # state, rate, jitter p50/p99/max, overruns, stress, faults
    kill -HUP <pid>                     # re-read config and model; a bad one is refused
    gma-ffc stop                        # ask, wait, SIGTERM if needed; safe current first
    scripts/install_service.sh --help   # install config/systemd/gma-ffc.service

Modules: `notify` (systemd's protocol without libsystemd), `paths` (the private runtime
directory), `control_socket` (protocol, client, peer-credential check), `control_server` (the
bounded event-loop server), `control_plane` (that server in a process of its own, answering
status from a snapshot), `runner` (the supervised foreground service), `daemon` (start/stop as
a background process), `status` (presentation).

From the controller the service needs only the contract in docs/ARCHITECTURE.md, plus two
status keys: `ticks` (grows while the loop makes progress: READY and watchdog pings follow it)
and `state` ("reconnecting" keeps the watchdog fed for a bounded time, "fault" makes `run` exit 1
so systemd's Restart=on-failure applies).
"""
