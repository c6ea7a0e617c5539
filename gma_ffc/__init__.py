"""gma-ffc: stress-dependent Prandtl-Ishlinskii modelling and feedforward control of GMAs."""

__version__ = "0.1.0"
