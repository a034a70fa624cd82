"""Sets dropped upstream, imitated: which frames of a clip a camera system under load would have
delivered. mvpose-eval thins its frames with it offline and mvpose-make-bag writes the thinned
bag the graph then plays, so both check the same frames."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class FrameDrop:
    """Leave out every `every`-th frame (positions every-1, 2 every-1, ...; 0 = none), then
    round(fraction x n) of the rest chosen at random with `seed`."""

    every: int = 0
    fraction: float = 0.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.every < 0 or not 0 <= self.fraction < 1:
            raise ValueError(f'drop every N >= 0 and a fraction in [0, 1), got {self.every}, {self.fraction}')

    def __bool__(self) -> bool:
        return bool(self.every or self.fraction)

    def kept(self, n: int) -> list[int]:
        """Positions (ascending) of the frames kept out of n."""
        keep = [k for k in range(n) if not (self.every and k % self.every == self.every - 1)]
        n_drop = round(self.fraction * len(keep))
        if n_drop:
            gone = set(np.random.default_rng(self.seed).choice(len(keep), n_drop, replace=False).tolist())
            keep = [k for i, k in enumerate(keep) if i not in gone]
        return keep

    @property
    def label(self) -> str:
        """A file-name-safe name of this drop, e.g. 'every2' or 'fraction0.3-seed1' ('' for none)."""
        parts = ([f'every{self.every}'] if self.every else []) + \
            ([f'fraction{self.fraction:g}-seed{self.seed}'] if self.fraction else [])
        return '-'.join(parts)
