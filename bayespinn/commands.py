"""Command implementations behind the CLI: turn parsed flags into library calls and files."""

from __future__ import annotations

import json
import logging
import sys
from dataclasses import replace
from pathlib import Path

from .config import parse_snr
from .errors import InputError
from .executor import Executor
from .methods import parse as parse_methods
from .options import RunOptions, config_from_args, default_out, resolve_device

log = logging.getLogger("bayespinn")


def writable_out(path: str | Path, *, folder: bool) -> Path:
    """`--out` checked before any work starts: a run that trains for minutes must not find at its end that
    it cannot write. `folder`: the command writes a folder there (else one file). The nearest part of the
    path that exists must be a folder this user can create entries in (probed by creating and removing a
    temporary one, which also catches read-only mounts), and the path itself, if it exists, of the right kind.
    `pipeline.staged_output` creates the folder only when the results are ready; this check is the
    command line's, made before any of the library's work starts.
    """
    import tempfile

    path = Path(path)
    kind = "folder" if folder else "file"
    if path.exists() and path.is_dir() != folder:
        raise InputError(
            "--out", str(path), f"a {kind} path, not an existing {'file' if folder else 'folder'}"
        )
    probe_in = path if path.is_dir() else path.parent
    while not probe_in.exists():
        probe_in = probe_in.parent
    if not probe_in.is_dir():
        raise InputError(
            "--out", str(path), f"a {kind} path below folders only ({probe_in} is a file)"
        )
    try:
        Path(tempfile.mkdtemp(dir=probe_in, prefix=".bayespinn-probe-")).rmdir()
    except OSError as e:
        raise InputError(
            "--out", str(path), f"a {kind} path this user can write ({probe_in}: {e.strerror or e})"
        ) from None
    return path


def _opts(args, snr_db) -> RunOptions:
    return RunOptions(
        profile=args.profile,
        members=args.members,
        device=resolve_device(args.device),
        noise_prior=args.noise_prior,
        bpinn_variant=args.bpinn_variant,
        snr_db=snr_db,
        progress=not args.quiet,
        executor=Executor(args.executor, args.workers, args.address),
    )


def cmd_run(args) -> int:
    if args.data is None and args.snr is None:
        raise InputError(
            "--snr", None, "'clean' or a finite number of dB > 0 (or give --data FILE.csv)"
        )
    snr = parse_snr(args.snr) if args.snr is not None else None
    cfg = config_from_args(args)
    methods = parse_methods(args.method)
    opts = _opts(args, snr)
    if args.noise_prior == "snr" and (args.data is not None or snr is None):
        if args.snr is None:
            raise InputError(
                "--noise-prior", "snr", "a nominal --snr in dB to centre the noise prior on"
            )
    out = writable_out(args.out or default_out(args), folder=True)
    from .pipeline import run

    res = run(
        cfg, methods=methods, snr_db=snr, seed=args.seed, data_path=args.data, out=out, opts=opts
    )
    log.info("wrote %s", out)
    sys.stdout.write(closing_lines(res, out))
    return 0


def closing_lines(res, out) -> str:
    """The end of `bayespinn run` on the terminal: the methods' table and the headline of the report
    (`report.headline`), on stdout, whatever --quiet says (it silences progress, not the answer)."""
    from .report.headline import cached_answer, strip_marks
    from .report.units import name

    rows = [("method", "EI (GN·m²)", "90 % interval", "fit check", "vs reference")]
    from .uq.agreement import REFERENCE_KEY, agreement

    verdicts = {v.method: v for v in agreement(res.summary["methods"])}
    for k, m in res.summary["methods"].items():
        e = m["EI"]
        v = verdicts.get(k)
        rows.append(
            (
                name(k),
                f"{e['mean'] / 1e9:.4f}",
                f"[{e['ci90'][0] / 1e9:.4f}, {e['ci90'][1] / 1e9:.4f}]",
                str((m.get("fit_check") or {}).get("verdict", "n/a")),
                "reference" if k == REFERENCE_KEY else strip_marks(v.label) if v else "n/a",
            )
        )
    widths = [max(len(r[i]) for r in rows) for i in range(len(rows[0]))]
    table = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    head = cached_answer(res).lines()
    return "\n".join(["", *table, "", *head, f"Report: {Path(out) / 'report.html'}", ""])


def cmd_coverage(args) -> int:
    from .data.measurements import atomic_write_text
    from .uq.coverage import coverage_study
    from .uq.posterior import jsonable

    if args.snr is None:
        raise InputError(
            "--snr", None, "'clean' or a finite number of dB > 0 (required for coverage)"
        )
    snr = parse_snr(args.snr)
    if snr is None:
        raise InputError(
            "--snr", args.snr, "a finite number of dB > 0 (clean data have no noise to cover)"
        )
    if args.truth not in ("fixed", "prior"):
        raise InputError("--truth", args.truth, "fixed or prior")
    cfg = config_from_args(args)
    method = parse_methods(args.method if args.method != "all" else "modal", single=True)[0]
    opts = _opts(args, snr)
    out = writable_out(
        args.out
        or Path("reports")
        / "coverage"
        / f"{method}-{args.case}-snr{args.snr}-seed{args.seed}.json",
        folder=False,
    )
    # finished replicates survive an interruption here; the same command resumes from them
    partial = out.with_name(out.name + ".partial.jsonl")
    res = coverage_study(
        method,
        cfg,
        snr,
        replicates=args.replicates,
        level=args.level,
        seed=args.seed,
        truth=args.truth,
        opts=replace(opts, executor=None),
        executor=opts.executor,
        progress=not args.quiet,
        checkpoint=partial,
        resume_from=out if args.resume else None,
    )
    atomic_write_text(out, json.dumps(jsonable(res), indent=2) + "\n")
    partial.unlink(missing_ok=True)
    log.info(
        "%s coverage at %s dB: %d / %d = %.3f (95%% CI [%.3f, %.3f]), rank-uniformity p = %.3f, %.1f s -> %s",
        res["method"],
        args.snr,
        res["hits"],
        res["replicates"],
        res["coverage"],
        *res["coverage_ci95"],
        res["rank_uniformity_p"],
        res["runtime_s"],
        out,
    )
    return 0


def cmd_sweep(args) -> int:
    from .sweep import sweep

    if args.snr is None:
        raise InputError("--snr", None, "a comma list of levels, e.g. clean,10,20,30,40")
    levels = [parse_snr(s) for s in args.snr.split(",")]
    cfg = config_from_args(args)
    methods = parse_methods(args.method)
    opts = _opts(args, None)
    out = writable_out(
        args.out or Path("reports") / "sweeps" / f"{args.case}-seed{args.seed}", folder=True
    )
    sweep(cfg, levels=levels, methods=methods, seed=args.seed, out=out, opts=opts)
    log.info("wrote %s", out)
    return 0


def cmd_bench(args) -> int:
    from .bench import bench
    from .data.measurements import atomic_write_text
    from .uq.posterior import jsonable

    device = resolve_device(args.device)
    if args.out:
        writable_out(args.out, folder=False)
    res = bench(device=device, progress=not args.quiet, run=args.run)
    text = json.dumps(jsonable(res), indent=2) + "\n"
    if args.out:
        atomic_write_text(args.out, text)
    else:
        sys.stdout.write(text)
    return 0
