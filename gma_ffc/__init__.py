"""gma-ffc: stress-dependent Prandtl-Ishlinskii modelling and feedforward control of GMAs."""

import os as _os

# Our matrices are small (thousands x tens): multi-threaded BLAS only makes threads fight over
# the cores, 5-8x slower identification on a 2-core lab PC, and steals time from the control
# loop. Single-threaded unless the user says otherwise; effective when gma_ffc is imported
# before numpy, as the console script does.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    _os.environ.setdefault(_var, "1")

__version__ = "0.1.0"
