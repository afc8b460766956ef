"""Many networks trained as one: networks x training steps per second at N networks batched (the way the
ensemble's members train on CUDA) beside one network at a time (`bayespinn bench`'s many_networks)."""

from __future__ import annotations

import time

import torch

from .bench import _deflection_problem, _member_settings, _sync

#: how many networks `bench_many_networks` trains as one by default
MANY_NETWORKS = (1, 8, 64, 256)


def bench_many_networks(
    counts: tuple[int, ...] = MANY_NETWORKS,
    points: int = 1000,
    width: int = 64,
    depth: int = 5,
    device: str = "cpu",
    *,
    seconds: float = 3.0,
    min_steps: int = 2,
    optimizer: str = "adam",
) -> dict:
    """Networks x training steps per second when N networks train as one (batched weights (N, d_in, d_out),
    as the ensemble's members train on CUDA), for each N in `counts`, on `device`, beside one network at
    a time (N = 1, the same step).

    Each N gets a warm-up step and then as many full training steps as fit in `seconds` (at least
    `min_steps`); the figure is N x steps / wall time. `ratio_vs_one` divides by the figure at N = 1 measured
    in the same call. Returns {"device", "points", "width", "depth", "rows": [{"networks",
    "networks_steps_per_s", "ms_per_step", "steps", "ratio_vs_one"}]}; a count that does not fit in
    memory is recorded with its error instead of ending the benchmark.
    """
    from .train import _Trainer  # the training loop's own step

    dev = torch.device(device)
    prob = _deflection_problem()
    s = _member_settings(points, width, depth, optimizer)
    rows = []
    for n in counts:
        try:
            tr = _Trainer(prob, s, 0, n, dev)
            tr.adam_step()  # warm-up
            _sync(dev)
            t0, steps = time.perf_counter(), 0
            while steps < min_steps or time.perf_counter() - t0 < seconds:
                tr.adam_step()
                steps += 1
            _sync(dev)
            dt = time.perf_counter() - t0
            rows.append(
                {
                    "networks": n,
                    "steps": steps,
                    "ms_per_step": 1e3 * dt / steps,
                    "networks_steps_per_s": n * steps / dt,
                }
            )
            del tr
        except (RuntimeError, MemoryError) as exc:  # out of memory on this device
            rows.append({"networks": n, "error": f"{type(exc).__name__}: {str(exc)[:200]}"})
            if dev.type == "cuda":
                torch.cuda.empty_cache()
    one = next(
        (r["networks_steps_per_s"] for r in rows if r["networks"] == 1 and "error" not in r), None
    )
    for r in rows:
        if one and "networks_steps_per_s" in r:
            r["ratio_vs_one"] = r["networks_steps_per_s"] / one
    return {"device": str(dev), "points": points, "width": width, "depth": depth, "rows": rows}
