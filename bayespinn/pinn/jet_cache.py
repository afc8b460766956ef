"""The enrichments' cache of jets (`pinn.enrich`): the jets of the last few point sets an enrichment was
asked for, keyed by the very tensors, so that the sine series and the free vibrations' fixed parts are not
recomputed for the data points (which never change during a fit) or for collocation points between
resamplings. Kept apart from the enrichments it serves; not kept while torch.compile traces.
"""

from __future__ import annotations

from collections import OrderedDict

import torch
from torch import Tensor

from .taylor import Jet


def _compiling() -> bool:
    f = getattr(torch.compiler, "is_compiling", None)  # torch >= 2.3
    return bool(f()) if f is not None else bool(torch._dynamo.is_compiling())


class _JetCache:
    """The jets of the last `size` point sets, keyed by the very tensors (identity and version, so a new or
    modified tensor is a miss). Not kept for points that carry gradients, nor while torch.compile traces;
    not pickled (a copy starts empty)."""

    def __init__(self, size: int = 8):
        self.size = size
        self.items: OrderedDict = OrderedDict()

    @staticmethod
    def usable(xi: Tensor, tau: Tensor) -> bool:
        return not (xi.requires_grad or tau.requires_grad or _compiling())

    def get(self, xi: Tensor, tau: Tensor, kx: int, kt: int, make) -> Jet:
        if not self.usable(xi, tau):
            return make()
        key = (id(xi), id(tau), kx, kt)
        hit = self.items.get(key)
        # the entry holds its tensors, so their ids cannot be reused while it lives
        if (
            hit is not None
            and hit[0] is xi
            and hit[1] is tau
            and hit[2] == (xi._version, tau._version)
        ):
            self.items.move_to_end(key)
            return hit[3]
        jet = make()
        self.items[key] = (xi, tau, (xi._version, tau._version), jet)
        while len(self.items) > self.size:
            self.items.popitem(last=False)
        return jet

    def __getstate__(self) -> dict:
        return {"size": self.size}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["size"])
