"""The service around the controller: `gma-ffc run` (foreground, systemd Type=notify),
`start`/`stop`/`status` over an owner-only Unix socket, SIGHUP reload.

Modules: `notify` (systemd's protocol without libsystemd), `paths` (the private runtime
directory), `control_socket` (server, client, peer-credential check), `runner` (the supervised
foreground service), `daemon` (start/stop as a background process), `status` (presentation).
"""
