"""Benchmark fixtures: seeded cases on the simulated rig (hil_sim), shared by scripts/ and tests/.

Not part of the installed package: the tool never needs its own benchmark to run. Scripts and
tests import it from the checkout (pytest's `pythonpath` and each script's sys.path line).
"""
