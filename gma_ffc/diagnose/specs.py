"""A model under test and how it scored: the value types the diagnosis' fitting, search and
selection pass between them.

- `Spec`: effect name -> the effect's nonlinear parameter; hashable, so fits and core runs are
  cached by it.
- `Score`: one spec's two-fold held-out-block figures and its all-data fit.
- `LeftOut`, `LeaveOneOut`: one recording predicted by a fit on the others, and all of them.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Iterable, Iterator, Mapping, Sequence

import numpy as np


def _plain(p: Any) -> Any:
    """A parameter as plain Python (grid points may be numpy scalars): equal values, equal specs."""
    if isinstance(p, (bool, np.bool_)):
        return bool(p)
    if isinstance(p, (tuple, list, np.ndarray)):
        return tuple(float(v) for v in p)
    if dataclasses.is_dataclass(p) and not isinstance(p, type):    # a point's form (creep from rest): its fields plain
        return dataclasses.replace(p, **{f.name: _plain(getattr(p, f.name)) for f in dataclasses.fields(p)})
    return float(p)


class Spec(Mapping[str, Any]):
    """A model under test: effect name -> its nonlinear parameter (time constant, delay, resonance
    (f_ref_hz, zeta, beta_per_MPa), width chord step, True). An effect not in it is absent.
    Hashable and order-free, so fits and core runs are cached by spec."""

    __slots__ = ("_items",)

    def __init__(self, items: Mapping[str, Any] | Iterable[tuple[str, Any]] = ()) -> None:
        self._items = tuple(sorted((k, _plain(v)) for k, v in dict(items).items()))

    def __getitem__(self, name: str) -> Any:
        for k, v in self._items:
            if k == name:
                return v
        raise KeyError(name)

    def __iter__(self) -> Iterator[str]:
        return (k for k, _ in self._items)

    def __len__(self) -> int:
        return len(self._items)

    def __hash__(self) -> int:
        return hash(self._items)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Spec) and self._items == other._items

    def __repr__(self) -> str:
        return f"Spec({dict(self._items)!r})"

    def with_(self, name: str, p: Any) -> "Spec":
        return Spec({**dict(self._items), name: p})

    def without(self, name: str) -> "Spec":
        return Spec({k: v for k, v in self._items if k != name})


@dataclass
class Score:
    """Results of one spec: per-fold train/test loss (Huber when set, else squared error), the
    test folds' plain squared error, and the all-data fit."""

    sse_train: tuple[float, float]
    sse_test: tuple[float, float]
    n_train: tuple[int, int]
    n_test: tuple[int, int]
    sse_all: float
    n_all: int
    coef_all: np.ndarray | None
    names: list[str]
    sq_test: tuple[float, float] = (math.nan, math.nan)   # plain squared error on the test folds

    def train_mse(self, fold: int) -> float:
        return self.sse_train[fold] / max(self.n_train[fold], 1)

    @property
    def all_mse(self) -> float:
        return self.sse_all / max(self.n_all, 1)

    @property
    def n_held_out(self) -> int:
        return self.n_test[0] + self.n_test[1]

    @property
    def held_out_loss(self) -> float:
        """Both folds' test loss per held-out sample (one spec scored on both folds)."""
        return (self.sse_test[0] + self.sse_test[1]) / max(self.n_held_out, 1)

    @property
    def held_out_mse(self) -> float:
        """Both folds' plain squared test error per held-out sample."""
        return (self.sq_test[0] + self.sq_test[1]) / max(self.n_held_out, 1)


@dataclass(frozen=True)
class LeftOut:
    """One recording predicted by a fit on the others: the training loss per sample there, and on
    the left-out recording the loss, the squared error and the sample count."""

    train_loss: float
    loss: float
    sse: float
    n: int


@dataclass(frozen=True)
class LeaveOneOut:
    """Leave-one-recording-out: per recording, the loss, squared error and count when it was left
    out of the fit; and the effect parameter chosen without it (None: none was searched)."""

    loss: tuple[float, ...]
    sse: tuple[float, ...]
    n: tuple[int, ...]
    params: tuple[Any, ...] = ()

    @property
    def loss_per_sample(self) -> float:
        return sum(self.loss) / max(sum(self.n), 1)

    @property
    def mse(self) -> float:
        return sum(self.sse) / max(sum(self.n), 1)

    def without(self, k: int) -> "LeaveOneOut":
        """The same figures with recording `k`'s left out of the pool (a recording whose fold tests
        nothing: see `Problem.sole_setter`)."""
        drop = lambda xs, zero: tuple(zero if i == k else x for i, x in enumerate(xs))  # noqa: E731
        return LeaveOneOut(drop(self.loss, 0.0), drop(self.sse, 0.0), drop(self.n, 0), self.params)

    @classmethod
    def of(cls, parts: Sequence[LeftOut], params: Sequence[Any] = ()) -> "LeaveOneOut":
        return cls(tuple(p.loss for p in parts), tuple(p.sse for p in parts), tuple(p.n for p in parts),
                   tuple(params))
