"""One root seed, split into independent named streams (numpy SeedSequence).

Every stochastic function of bayespinn takes a SeedSequence (or an int) from here; nothing seeds a
global generator. A stream's identity is its name, so adding a new stream never changes the numbers
of the others.
"""

from __future__ import annotations

import zlib

import numpy as np

STREAMS = (
    "points",
    "noise",
    "emcee",
    "collocation",
    "ensemble",
    "pyro",
    "coverage",
    "init",
    "pyro-full",
    "importance",
)


def stream(seed: int | np.random.SeedSequence, name: str) -> np.random.SeedSequence:
    """The independent SeedSequence called `name` under a root seed."""
    if name not in STREAMS:
        raise ValueError(f"unknown random stream {name!r}; known: {', '.join(STREAMS)}")
    key = zlib.crc32(name.encode())
    if isinstance(seed, np.random.SeedSequence):
        return np.random.SeedSequence(seed.entropy, spawn_key=tuple(seed.spawn_key) + (key,))
    return np.random.SeedSequence(int(seed), spawn_key=(key,))


def rng(seed: int | np.random.SeedSequence, name: str) -> np.random.Generator:
    """A numpy Generator on the named stream."""
    return np.random.default_rng(stream(seed, name))


def child(seed: int | np.random.SeedSequence, name: str, index: int) -> np.random.SeedSequence:
    """The index-th independent child of a named stream (ensemble member, coverage replicate, chain)."""
    s = stream(seed, name)
    return np.random.SeedSequence(s.entropy, spawn_key=tuple(s.spawn_key) + (int(index),))


def int_seed(seq: np.random.SeedSequence) -> int:
    """A 63-bit integer seed from a SeedSequence (for torch.Generator and emcee's numpy state)."""
    return int(seq.generate_state(2, np.uint64)[0] >> np.uint64(1))
