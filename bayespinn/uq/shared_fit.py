"""One PINN fit for the methods that see the same data: the B-PINN starts from the ensemble's member 0.

The deep ensemble's first phase fits M networks to the measured data; the B-PINN's last-layer posterior
needs one such fit. Both are defined as the same computation, member 0 of the ensemble's first phase
(`member_fit`: seed stream "init" of the ensemble's seed, one member, one torch thread on a CPU), so the
B-PINN's result is a function of the run's seed whether or not the ensemble ran before it: when it did, the
fit is taken from this process's cache (`remember`/`recall`, keyed by everything that decides the fit);
when it did not, the B-PINN computes the very same fit itself (bit for bit: the same seeds, settings and
single thread). On a GPU the ensemble trains its members as one batched network, whose member 0 is only
statistically equivalent to the single fit, so nothing is shared there and the B-PINN fits its own.

The cache holds the last `CACHE_SIZE` fits of this process (a coverage study's replicates each see new
data, so older fits are never asked for again).
"""

from __future__ import annotations

import hashlib
import json
import logging
from collections import OrderedDict
from dataclasses import asdict

import numpy as np

from .. import seeding
from ..threads import torch_threads

log = logging.getLogger(__name__)

CACHE_SIZE = 2
_CACHE: OrderedDict[str, object] = OrderedDict()


def ensemble_seed(seed) -> np.random.SeedSequence:
    """The deep ensemble's seed under a run's root seed."""
    return seeding.stream(seed, "ensemble")


def member_seed(ens_seed) -> np.random.SeedSequence:
    """The seed of the ensemble's first-phase fits (member m draws its streams from (this, m))."""
    return seeding.stream(ens_seed, "init")


def key(problem, settings, seed: np.random.SeedSequence, member: int) -> str:
    """What decides a fit: the problem (girder, axles, data, EI_ref and the objective's extras), the
    training settings, the seed and the member index."""
    h = hashlib.sha256()
    d = problem.datasets
    for m in d:
        for a in (m.x, m.t, m.value, m.y, m.kind, m.sensor):
            h.update(np.ascontiguousarray(a).tobytes())
    spec = {
        "beam": asdict(problem.beam),
        "vehicle": repr(problem.vehicle),
        "EI_ref": problem.EI_ref,
        "beta": problem.beta,
        "noise_sd": problem.noise_sd,
        "anchor": repr(problem.anchor),
        "duration": problem.duration,
        "settings": repr(settings),
        "seed": [str(seed.entropy), list(seed.spawn_key)],
        "member": int(member),
    }
    h.update(json.dumps(spec, sort_keys=True, default=repr).encode())
    return h.hexdigest()


def remember(k: str, result) -> None:
    _CACHE[k] = result
    _CACHE.move_to_end(k)
    while len(_CACHE) > CACHE_SIZE:
        _CACHE.popitem(last=False)


def recall(k: str):
    """The fit stored under k in this process, or None."""
    return _CACHE.get(k)


def clear() -> None:
    _CACHE.clear()


def member_fit(problem, settings, seed, member: int, *, quiet: bool = True, callback=None):
    """Member `member` of the ensemble's first phase, alone on one CPU thread (`pinn.fit`)."""
    from ..pinn import fit

    with torch_threads(1):
        return fit(
            problem,
            settings,
            seed=seed,
            members=1,
            first_member=member,
            device="cpu",
            quiet=quiet,
            callback=callback,
        )
