"""The model contract (docs/ARCHITECTURE.md) as typing protocols.

Every model kind (`SDPIModel` for sdpi and mpi, the diagnose tool's extended model, a lab's own)
is used by the controller, the SIL harness, the CLI and `modelio` only through these members, so
they are annotated with `Model` rather than a concrete class or `Any`: mypy then checks that a
caller asks for nothing beyond the contract, and that each model class still offers all of it.

The protocols are `runtime_checkable` so a test can assert that the shipped classes satisfy
them (isinstance checks names only; mypy checks the signatures, see tests/test_protocols.py).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from .initial_state import ResolvedInitialState


@runtime_checkable
class ForwardStepper(Protocol):
    """One drive sample in, one displacement (um) out; state kept between calls, no allocation."""

    def step(self, drive: float, stress_MPa: float, /) -> float: ...

    def reset(self, initial_drive: float = 0.0) -> None:
        """Back to the state a new stepper starts in at `initial_drive` (the model's convention:
        an SDPI file's `initial_state`, "descending" or "relaxed")."""
        ...


@runtime_checkable
class InverseStepper(Protocol):
    """One reference sample (um) in, one drive out; state kept between calls, no allocation."""

    def step(self, reference_um: float, stress_MPa: float, /) -> float: ...

    def reset(self, initial_drive: float = 0.0) -> None:
        """Back to the state a new stepper starts in at `initial_drive` (the model's convention:
        an SDPI file's `initial_state`, "descending" or "relaxed")."""
        ...


@runtime_checkable
class Model(Protocol):
    """What every model kind offers (docs/ARCHITECTURE.md, "Model contract")."""

    @property
    def kind(self) -> str:
        """"sdpi" | "mpi" | "extended" | a registered kind: the file's `kind`."""
        ...

    @property
    def stress_range_MPa(self) -> tuple[float, float] | None:
        """(lo, hi) the model was identified on; None when it ignores stress (MPI)."""
        ...

    @property
    def drive_range(self) -> tuple[float, float]:
        """(lo, hi) of the drive it was identified on."""
        ...

    @property
    def drive_name(self) -> str: ...

    @property
    def preview_s(self) -> float:
        """How far ahead the inverse stepper's reference must be (a modelled transport delay)."""
        ...

    def simulate(self, time_s: Any, drive: Any, stress_MPa: Any = None, *,
                 initial_state: Any = None, measured_um: Any = None) -> np.ndarray: ...

    def invert(self, time_s: Any, reference_um: Any, stress_MPa: Any = None) -> np.ndarray: ...

    def forward_stepper(self, dt_s: float, initial_drive: float = 0.0) -> ForwardStepper: ...

    def inverse_stepper(self, dt_s: float, initial_drive: float = 0.0) -> InverseStepper: ...

    def resolve_initial_state(self, drive: Any, stress_MPa: Any = None, initial_state: Any = None,
                              measured_um: Any = None, time_s: Any = None) -> ResolvedInitialState: ...

    def to_dict(self) -> dict[str, Any]: ...
