"""`run`: data -> posteriors of each method -> a report folder, written all-or-nothing."""

from __future__ import annotations

import json
import logging
import shutil
import sys
import tempfile
import time
from collections.abc import Iterable
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from . import methods as registry
from .config import Config
from .data.measurements import Measurements, read_csv
from .data.synthetic import realised_snr, sigma_for_snr, simulate
from .errors import InputError
from .options import PROFILES, RunOptions
from .provenance import git_commit, git_dirty, machine, now, versions
from .uq.posterior import Posterior, jsonable

log = logging.getLogger(__name__)

#: deflections above this are almost surely in mm, strains above this in microstrain
WRONG_UNIT = {"deflection": 0.5, "strain": 1e-2}


@dataclass
class RunResult:
    """What `analyse` produced: data, truth (or None), posteriors by summary key, the summary dict (what
    summary.json holds), the manifest and the configuration."""

    data: Measurements
    truth: dict | None
    posteriors: dict[str, Posterior]
    summary: dict
    manifest: dict
    config: Config | None = None


def unit_warnings(data: Measurements) -> list[str]:
    """Warnings for values that look like the wrong unit (mm or microstrain instead of SI)."""
    out = []
    for kind, lim in WRONG_UNIT.items():
        v = np.abs(data.value[data.kind == kind])
        if v.size and float(v.max()) > lim:
            unit = "m" if kind == "deflection" else "strain (dimensionless)"
            out.append(
                f"{kind} values up to {float(v.max()):.3g} look like the wrong unit: files are SI ({unit})"
            )
    return out


def load_data(
    cfg: Config, data_path: str | None, snr_db: float | None, seed: int
) -> tuple[Measurements, dict | None]:
    """Measured data (truth None) or synthetic data at snr_db (truth: EI and sigma)."""
    if data_path is not None:
        data = read_csv(data_path, cfg.beam.length)
        cases = set(data.kind.tolist())
        if cfg.case not in cases and len(cases) == 1:
            cfg_case = next(iter(cases))
            raise InputError(
                "--case", cfg.case, f"'{cfg_case}' to match the kind of the rows in {data_path}"
            )
        return data, None
    data = simulate(cfg, snr_db, seed)
    sigma = sigma_for_snr(data.value_true, snr_db)
    return data, {**true_values_of(cfg, seed), "sigma": sigma}


def _contract_entry(entry: dict) -> dict:
    """A method's summary entry in the contract's keys: the deep ensemble on a real girder keeps each member's
    figures as a list under `members`; the contract wants the count there and each member's EI in
    `member_EI` (here the span-equivalent EI, S / sum 1 / EI_s, of the member's geometric-mean segment EIs),
    the per-member figures moving to `member_details`."""
    m = entry.get("members")
    if isinstance(m, list) and m and isinstance(m[0], dict) and "EI_segments" in m[0]:
        entry = dict(entry)
        entry["member_details"] = m
        entry["members"] = len(m)
        entry["member_EI"] = [
            len(d["EI_segments"]) / sum(1.0 / e for e in d["EI_segments"]) for d in m
        ]
    return entry


def true_values_of(cfg: Config, seed) -> dict:
    """The synthetic truth in the contract's keys: EI (for EI per segment, the span-averaged flexibility's
    equivalent), and for the analysis model's extra parameters EI_segments (per analysis segment),
    rotational_stiffness [left, right] and load_factor."""
    out: dict = {"EI": cfg.beam.EI}
    if cfg.model.EI_field == "smooth":
        from .data.girder_data import field_truth
        from .uq.girder_field import field_grid

        out.update(field_truth(cfg, field_grid(cfg.beam.length)))
    if cfg.ideal and cfg.beam.ideal and cfg.vehicle.load_rel_sd == 0:
        return out
    from .data.girder_data import girder_truth
    from .data.synthetic import true_load_factor
    from .physics.girder import Girder

    b = cfg.beam
    girder = Girder.from_beam(b, b.segments, b.rotational_stiffness)
    t = girder_truth(girder, cfg.model.EI_segments, true_load_factor(cfg, seed))
    if cfg.model.EI_segments > 1:
        out["EI_segments"] = t["EI_segments"]
    if cfg.model.supports == "springs":
        out["rotational_stiffness"] = t["rotational_stiffness"]
    if cfg.vehicle.load_rel_sd > 0:  # a truth of the data, whether or not the analysis infers it
        out["load_factor"] = t["load_factor"]
    return out


@contextmanager
def staged_output(out: Path):
    """Yield a staging folder; on success move its files into `out`, on failure leave `out` untouched."""
    created = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=".partial-", dir=out))
    try:
        yield stage
        for f in sorted(stage.iterdir()):
            # summary.json last, so a reader that sees it sees everything
            if f.name != "summary.json":
                f.replace(out / f.name)
        if (stage / "summary.json").exists():
            (stage / "summary.json").replace(out / "summary.json")
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        if created and not any(out.iterdir()):
            out.rmdir()
        raise
    shutil.rmtree(stage, ignore_errors=True)


def analyse(
    data: Measurements,
    cfg: Config,
    *,
    methods: Iterable[str] | str = ("modal", "ensemble", "bpinn"),
    seed: int = 0,
    profile: str = "fast",
    truth: dict | None = None,
    snr_db: float | None = None,
    opts: RunOptions | None = None,
    argv: list[str] | None = None,
    data_source: str = "in memory",
) -> RunResult:
    """Run each method on the data, in memory: no file is written (`write_run` writes the run folder).

    Parameters
    ----------
    data : the measurements (`simulate` or `read_csv`)
    cfg : the bridge, vehicle and prior (`resolve`)
    methods : CLI names ("modal", "ensemble", "bpinn", or a registered method's), a comma string, or
        "all"; or `bayespinn.methods.Method` instances built with their own settings
    seed : the root seed; the result is a function of it
    profile : "smoke", "fast" or "paper" (ignored when `opts` is given)
    truth : {"EI": N m^2, "sigma": ...} of synthetic data, or None for measured data
    snr_db : the nominal SNR of synthetic data [dB] (the `snr` noise prior is centred on it), or None
    opts : every method option at once (`options.RunOptions`), as the command line builds them

    Returns
    -------
    RunResult with `posteriors` by summary key (the reference's: `methods.REFERENCE_KEY`), `summary` (what
    summary.json holds) and `manifest`.
    """
    t_start = time.perf_counter()
    if opts is None:
        if profile not in PROFILES:
            raise InputError("profile", profile, "smoke, fast or paper")
        opts = RunOptions(profile=profile)
    opts = replace(opts, snr_db=snr_db)
    chosen = _methods(methods, opts)
    if truth is not None and not (isinstance(truth, dict) and _positive(truth.get("EI"))):
        raise InputError("truth", truth, 'None, or a dict with "EI" > 0 in N m^2')
    vt = data.value_true
    synthetic = vt is not None and bool(np.all(np.isfinite(vt))) and bool(np.any(vt))
    if truth is not None and "sigma" not in truth and snr_db is not None and synthetic:
        truth = {**truth, "sigma": sigma_for_snr(vt, snr_db)}  # the noise level simulate used
    for m in chosen:  # every method's refusal before any of them runs
        m.check(data, cfg)
    for w in unit_warnings(data):
        log.warning("warning: %s", w)
    posts: dict[str, Posterior] = {}
    timings = {}
    for m in chosen:
        log.info("[%s] running on %d %s measurements", m.key, len(data), data.case)
        p = m.posterior(data, cfg, seed=seed)
        posts[m.key] = p
        timings[m.key] = p.runtime_s
        s = p.summary(truth)["EI"]
        log.info(
            "[%s] EI = %.4g N m^2 (sd %.3g, 90%% [%.4g, %.4g]) in %.1f s",
            m.key,
            s["mean"],
            s["sd"],
            s["ci90"][0],
            s["ci90"][1],
            p.runtime_s,
        )
    checks = fit_checks(posts, data, cfg, seed)
    summary = {
        "schema": "bayespinn.summary/1",
        "case": cfg.case,
        "snr_db": snr_db,
        "seed": seed,
        "profile": opts.profile,
        "truth": truth,
        "methods": {k: _contract_entry(p.summary(truth)) for k, p in posts.items()},
    }
    for k, fc in checks.items():
        summary["methods"][k]["fit_check"] = fc
    if snr_db is not None and synthetic:
        summary["realised_snr_db"] = realised_snr(data.value, data.value_true)
    agree = agreement_entries(summary["methods"])
    if agree:
        summary["agreement"] = agree
    timings["total_s"] = time.perf_counter() - t_start
    manifest = {
        "schema": "bayespinn.manifest/1",
        "command": list(argv) if argv is not None else list(sys.argv),
        "config": cfg.to_dict(),
        "seed": seed,
        "snr_db": snr_db,
        "data": data_source,
        "methods": list(posts),
        "options": {
            "profile": opts.profile,
            "members": opts.members,
            "noise_prior": opts.noise_prior,
            "device": opts.device,
            "bpinn_variant": opts.bpinn_variant,
        },
        "device": opts.device,
        "machine": machine(opts.device),
        "versions": versions(),
        "git_commit": git_commit(),
        "git_dirty": git_dirty(),
        "date": now(),
        "timings_s": timings,
        "time_breakdown_s": time_breakdown(posts),
    }
    return RunResult(data, truth, posts, summary, manifest, cfg)


def fit_checks(posts: dict[str, Posterior], data: Measurements, cfg: Config, seed) -> dict:
    """Each method's fit check (`uq.fitcheck`) by summary key; a misfit is logged as a warning. A method
    without a predictor, or too few data, gets none; a check that fails to run costs a warning, not the run."""
    from .uq import fitcheck

    out = {}
    duration = max(cfg.duration, float(np.max(data.t))) if len(data) else cfg.duration
    s = seed if isinstance(seed, int) else 0
    for k, p in posts.items():
        try:
            fc = fitcheck.check(p, data, cfg.beam.length, duration, seed=s)
        except Exception as exc:  # noqa: BLE001 - a broken predictor must not lose the run
            log.warning("warning: [%s] the fit check could not run (%s)", k, exc)
            continue
        if fc is None:
            continue
        out[k] = fc
        if fc["verdict"] == "misfit":
            log.warning(
                "warning: [%s] the data contradict the model (fit check p = %.2g): its intervals assume "
                "a model that does not explain these data",
                k,
                fc["p_value"],
            )
    return out


def time_breakdown(posteriors: dict[str, Posterior]) -> dict:
    """Where each method's wall time went [s], from what the methods record: the PINN training
    (`fit_runtime_s`: the B-PINN's one warm-start fit; the ensemble's member fits summed over its worker
    processes, so it can exceed the wall time) and the rest (the B-PINN's last-layer model and NUTS, the
    ensemble's pooling; everything for the modal reference)."""
    out = {}
    for k, p in posteriors.items():
        d = p.diagnostics or {}
        fit = d.get("fit_runtime_s")
        entry = {"wall": float(p.runtime_s)}
        if isinstance(fit, int | float) and fit >= 0:
            if d.get("fit_runtime_summed") or fit > p.runtime_s:
                entry["training_summed_over_workers"] = float(fit)
            else:
                entry["training"] = float(fit)
                entry["rest"] = float(p.runtime_s - fit)
        out[k] = entry
    return out


def _methods(methods, opts: RunOptions) -> list:
    """Method objects from CLI names (a list or a comma string) built with `opts`, or given instances."""
    if isinstance(methods, str):
        return [registry.build(n, opts) for n in registry.parse(methods)]
    items = list(methods)
    built = [m for m in items if isinstance(m, registry.Method)]
    names = [m for m in items if not isinstance(m, registry.Method)]
    if any(not isinstance(n, str) for n in names):
        raise InputError("methods", methods, "CLI names or bayespinn.methods.Method instances")
    out = built + [
        registry.build(n, opts) for n in (registry.parse(",".join(names)) if names else [])
    ]
    keys = [m.key for m in out]
    if len(set(keys)) != len(keys):
        raise InputError("methods", methods, "each method once")
    if not out:
        raise InputError("methods", methods, "at least one method")
    # the reference first, then registry order (the report compares each with the reference)
    order = {k: i for i, k in enumerate(registry.keys())}
    return sorted(out, key=lambda m: order.get(m.key, len(order)))


def _positive(v) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v) and v > 0


def write_run(result: RunResult, out: str | Path, *, report: bool = True) -> Path:
    """Write a run folder from an `analyse` result, all-or-nothing: data.csv, posterior_<key>.nc,
    report.md/html and figures (unless `report` is False), manifest.json, and summary.json last."""
    out = Path(out)
    with staged_output(out) as stage:
        result.data.to_csv(stage / "data.csv")
        seed = result.summary.get("seed") or 0
        for k, p in result.posteriors.items():
            _write_posterior(stage / f"posterior_{k}.nc", k, p, result.data, seed)
        manifest = result.manifest
        if report:
            from .report import write_reports

            log.info("[report] drawing the figures and writing the reports")
            t0 = time.perf_counter()
            write_reports(result, result.config, stage)
            # the file records the report's time; the result (which the report shows) stays as it was
            timings = {**manifest.get("timings_s", {}), "report_s": time.perf_counter() - t0}
            manifest = {**manifest, "timings_s": timings}
        _write_json(stage / "manifest.json", manifest)
        _write_json(stage / "summary.json", result.summary)
    return out


def _write_posterior(path: Path, key: str, post: Posterior, data: Measurements, seed) -> None:
    """posterior_<key>.nc with every group; when the method's predictor fails at the data points (e.g. a
    degenerate posterior whose output-weight covariance is not positive definite), the file is written
    without `posterior_predictive` and a warning says so, rather than losing the run."""
    try:
        post.to_netcdf(path, data=data, seed=seed)
    except Exception as exc:  # noqa: BLE001 - the draws must not be lost for a predictive check
        log.warning(
            "warning: [%s] posterior predictive at the data points failed (%s: %s); %s has no "
            "posterior_predictive group",
            key,
            type(exc).__name__,
            exc,
            path.name,
        )
        replace(post, predictor=None).to_netcdf(path, data=data, seed=seed)


def run(
    cfg: Config,
    *,
    methods: list[str],
    snr_db: float | None,
    seed: int = 0,
    data_path: str | None = None,
    out: str | Path,
    opts: RunOptions | None = None,
    argv: list[str] | None = None,
    write_report: bool = True,
) -> RunResult:
    """Simulate (or load) data, `analyse` it and `write_run` the contract's files into `out`."""
    data, truth = load_data(cfg, data_path, snr_db, seed)
    result = analyse(
        data,
        cfg,
        methods=methods,
        seed=seed,
        truth=truth,
        snr_db=snr_db if data_path is None else None,
        opts=opts or RunOptions(),
        argv=argv,
        data_source=str(data_path)
        if data_path
        else "synthetic (finite-element reference, point loads)",
    )
    write_run(result, out, report=write_report)
    return result


def agreement_entries(methods: dict) -> dict:
    """Each PINN posterior against the modal reference of the same data: EI mean difference and sigma mean
    difference in reference sds, the sd ratio, and the verdict (`report.agreement`)."""
    from .uq.agreement import agreement

    out = {}
    ref = methods.get(registry.REFERENCE_KEY)
    for v in agreement(methods):
        if v.agrees is None:
            continue
        entry = {"mean_diff_sd": v.mean_diff_sd, "sd_ratio": v.sd_ratio, "agrees": v.agrees}
        s, rs = methods[v.method].get("sigma", {}), ref.get("sigma", {})
        if rs.get("sd"):
            entry["sigma_diff_sd"] = (s["mean"] - rs["mean"]) / rs["sd"]
        out[v.method] = entry
    return out


def _write_json(path: Path, obj: dict) -> None:
    path.write_text(json.dumps(jsonable(obj), indent=2) + "\n", encoding="utf-8")
