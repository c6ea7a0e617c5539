"""hil_sim: the physically richer simulated GMA (plant.py) and, in emulators/, the devices around it.

`hil_sim.plant.GMAPlant` is the actuator; `python -m hil_sim record` writes recordings from it.
See docs/hil_sim.md for the physics and every parameter.
"""
