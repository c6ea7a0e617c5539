"""Shared test setup: import gma_ffc first so its single-threaded BLAS default applies."""

import gma_ffc  # noqa: F401  (sets OPENBLAS_NUM_THREADS before numpy loads)
