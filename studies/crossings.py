"""Realistic crossings, modal reference: EI's intervals and the fit check on recordings the analysis model
did not make, with the uncertain quantities declared and under today's model.

Each crossing is made by the independent simulator (`bayespinn.vbi`): the strain case's four-axle truck
with every axle a sprung mass, on a class A (even crossings) or class B (odd) ISO 8608 road, a true
speed, entry time, beam damping ratio and suspension drawn per crossing from the study's seed; the four
strain gauges of the strain case at the given SNR, the recording starting before the entry. The girders:
the Exeter preset (girder 0) and the first bridges of a family seed (`bayespinn.family`, strain case) with
the same truck. What the analysis is told is what a real crossing would give: the speed stated within
+-1.5 % of the truth and the entry time within +-0.1 s (both drawn uniformly), a damping ratio of 1 %, the
axle loads. Nothing else of the truth enters the analysis.

Each crossing is analysed twice by the modal reference:
(a) `declared`: speed_sd and entry_time_sd the sds of those uniform tolerances (1.5 % / sqrt(3),
    0.1 s / sqrt(3)), chosen from the tolerances before any result; [model] damping = "inferred" (the
    default prior); [model] axle_forces = "fluctuating" (or "constant" with --forces constant);
(b) `today`: nothing declared: the stated speed and entry time taken as exact, constant forces, the
    damping ratio the stated 1 %.
Per crossing: EI mean, sd, ci90, hit (truth inside the 90 % interval), z against the truth, the fit
check's verdict and p, the nuisances' posteriors, runtime. Summary: hits against the binomial 99 %
acceptance region of a calibrated 90 % interval, the "fits" rate of (a) (target >= 95 %), the "misfit"
rate of (b) (target >= 90 %), the z distribution. `--joint` analyses the first --joint crossings of
a girder together (`--joint-girder`, default 0; speeds and entry times per crossing, EI shared): its sd
against one crossing's.

Records: <out>/crossings/g<G>-c<K>.json (one per crossing, both analyses, with provenance), the study
<out>/crossings/study.json, the page <out>/crossings.md. Resumable: a crossing whose record exists with
this study's fingerprint is not recomputed.

    python studies/crossings.py --girders 3 --crossings 10 --out reports/paper
    python studies/crossings.py --girders 1 --crossings 10 --joint 10 --out reports/paper
"""

from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import logging
import math
import sys
import time
import zlib
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import common as c  # noqa: E402

from bayespinn import family  # noqa: E402
from bayespinn.config import Config, ModelSpec, Road, preset  # noqa: E402
from bayespinn.crossings.resonance import MODES as RESONANT_MODES  # noqa: E402
from bayespinn.provenance import provenance as _provenance  # noqa: E402
from bayespinn.uq.coverage import binomial_acceptance  # noqa: E402
from bayespinn.uq.sampler import MCMCSettings  # noqa: E402

log = logging.getLogger("studies.crossings")

STUDY_SCHEMA = "bayespinn.studies.crossings/1"
RECORD_SCHEMA = "bayespinn.studies.crossings-record/1"
#: the stated values' tolerances (uniform), and the analysis' sds: the sd of that uniform law
SPEED_TOL, ENTRY_TOL = 0.015, 0.1
SPEED_SD, ENTRY_SD = SPEED_TOL / math.sqrt(3), ENTRY_TOL / math.sqrt(3)
STATED_DAMPING = 0.01
#: the truths' ranges: speed [m/s], entry time [s], beam damping (log-uniform), suspension
SPEED_M_S, ENTRY_S, DAMPING, BODY_HZ, BODY_DAMPING = (
    (6, 12),
    (0.3, 0.8),
    (0.005, 0.02),
    (1.5, 3.5),
    (
        0.05,
        0.2,
    ),
)
ROADS = ("A", "B")
LEVEL, FALSE_FAILURE = 0.9, 0.01
FITS_TARGET, MISFIT_TARGET, SD_RATIO_TARGET = 0.95, 0.90, 0.45
#: emcee of every analysis here: two groups of 16 walkers, 30 autocorrelation times (the crossing
#: reference's own posterior tests use the same)
# (the chain on the linearised hyperparameters is capped at 2000 steps: where the linearisation fails its
# importance check, as on every crossing so far, it only places the first proposal of the importance
# sampler; where it passes, a chain stopped short fails its R-hat and ESS checks and says so)
MCMC = MCMCSettings(n_walkers=16, n_groups=2, tau_factor=30.0, min_steps=500, max_steps=2000)
SMOKE_MCMC = MCMCSettings(n_walkers=8, n_groups=2, tau_factor=5.0, min_steps=60, chunk=30)
_STREAM = zlib.crc32(b"crossings-study")


# ------------------------------------------------------------------------------------- the family
def girder(g: int, family_seed: int) -> Config:
    """Girder g: the Exeter preset (strain case) for g = 0, else bridge g - 1 of the family seed, with the
    strain case's truck and gauges at 20 samples per first-mode period (at least 100 Hz)."""
    base = preset("strain")
    if g == 0:
        return base
    cfg = family.bridge(g - 1, family_seed, "strain").cfg
    f1 = cfg.beam.natural_frequency(1) / (2 * math.pi)
    rate = max(100.0, 10.0 * math.ceil(2.0 * f1))
    return dataclasses.replace(
        cfg, vehicle=base.vehicle, data=dataclasses.replace(cfg.data, sample_rate=rate)
    )


def draw(seed: int, g: int, k: int) -> dict:
    """Crossing k of girder g: its truths, what is stated, and the data seed (a function of (seed, g, k))."""
    r = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(_STREAM, g, k)))
    speed = float(r.uniform(*SPEED_M_S))
    entry = float(r.uniform(*ENTRY_S))
    zeta = float(math.exp(r.uniform(math.log(DAMPING[0]), math.log(DAMPING[1]))))
    fb, zb = float(r.uniform(*BODY_HZ)), float(r.uniform(*BODY_DAMPING))
    du, dt = float(r.uniform(-1, 1)), float(r.uniform(-1, 1))
    return {
        "road": ROADS[k % 2],
        "speed": speed,
        "entry_time": entry,
        "damping_ratio": zeta,
        "body_frequency": fb,
        "body_damping": zb,
        "stated_speed": speed * (1 + SPEED_TOL * du),
        "stated_entry_time": entry + ENTRY_TOL * dt,
        "data_seed": int(r.integers(2**31)),
    }


def truth_config(gcfg: Config, d: dict) -> Config:
    veh = dataclasses.replace(
        gcfg.vehicle, speed=d["speed"], model="sprung", body_frequency=d["body_frequency"],
        body_damping=d["body_damping"], entry_time=d["entry_time"],
    )  # fmt: skip
    return dataclasses.replace(
        gcfg,
        beam=dataclasses.replace(gcfg.beam, damping_ratio=d["damping_ratio"]),
        vehicle=veh,
        road=Road(roughness=d["road"]),
    )


def stated_config(
    gcfg: Config, d: dict, declared: bool, forces: str, vehicle: str = "sprung"
) -> Config:
    """What the analysis is told: the stated speed and entry time, 1 % damping; with `declared`, their
    sds, inferred damping, the force model `forces` and the vehicle model `vehicle` ("sprung": each axle's
    body on a suspension of the default bounce frequency and damping, both inferred)."""
    veh = dataclasses.replace(
        gcfg.vehicle, speed=d["stated_speed"], entry_time=d["stated_entry_time"],
        speed_sd=SPEED_SD if declared else 0.0, entry_time_sd=ENTRY_SD if declared else 0.0,
        model=vehicle if declared else "forces",
    )  # fmt: skip
    model = ModelSpec(damping="inferred", axle_forces=forces) if declared else ModelSpec()
    return dataclasses.replace(
        gcfg,
        beam=dataclasses.replace(gcfg.beam, damping_ratio=STATED_DAMPING),
        vehicle=veh,
        model=model,
    )


def girder_for(args, g: int) -> Config:
    """Girder g of the study; at the smoke setting its gauges at 50 Hz (tests)."""
    cfg = girder(g, args.family_seed)
    if args.smoke:
        cfg = dataclasses.replace(cfg, data=dataclasses.replace(cfg.data, sample_rate=50.0))
    return cfg


def simulate(cfg: Config, snr: float, seed: int, smoke: bool):
    from bayespinn import vbi

    settings = vbi.VBISettings(n_elements=24, n_steps=400) if smoke else None
    return vbi.simulate(cfg, snr, seed, settings)


# -------------------------------------------------------------------------------------- analysing
def analyse(data, cfg: Config, ei_true: float, snr: float, seed: int, smoke: bool) -> dict:
    """One modal-reference analysis: the entries a record keeps."""
    import bayespinn as bp
    from bayespinn.methods.modal import ModalMCMC

    t0 = time.perf_counter()
    method = ModalMCMC(profile="smoke" if smoke else "fast", mcmc=SMOKE_MCMC if smoke else MCMC)
    res = bp.analyse(data, cfg, methods=[method], seed=seed, truth={"EI": ei_true}, snr_db=snr)
    m = res.summary["methods"]["modal_mcmc"]
    return entry(m, ei_true, time.perf_counter() - t0)


def entry(m: dict, ei_true: float, runtime: float) -> dict:
    e = m["EI"]
    fc = m.get("fit_check") or {}
    out = {
        "EI": {k: e[k] for k in ("mean", "sd", "ci90")},
        "hit": bool(e["ci90"][0] <= ei_true <= e["ci90"][1]),
        "z": (e["mean"] - ei_true) / e["sd"],
        "rel_error_pct": 100 * (e["mean"] / ei_true - 1),
        "fit_check": {k: fc.get(k) for k in ("verdict", "p_value", "reasons")},
        "runtime_s": runtime,
        "converged": (m.get("diagnostics") or {}).get("converged"),
        "problems": (m.get("diagnostics") or {}).get("problems") or [],
    }
    diag = m.get("diagnostics") or {}
    chk = (diag.get("linearisation") or {}).get("importance_check")
    imp = diag.get("importance")
    if imp:  # the exact posterior by importance sampling, the linearisation its guide
        out["importance"] = {k: imp[k] for k in ("passed", "ess", "khat", "rounds", "evaluated")}
    if chk:
        out["linearisation_check"] = {
            k: chk[k] for k in ("passed", "ess_fraction", "log_EI_shift_sd", "draws")
        }
    for k in (
        "speed",
        "entry_time",
        "damping_ratio",
        "axle_force_sd",
        "axle_force_correlation",
        "body_frequency",
        "body_damping",
        "crossing_error",
    ):
        if k in m:
            out[k] = {q: m[k][q] for q in ("mean", "sd", "ci90")}
    for name, ce in (m.get("crossings") or {}).items():  # several crossings: each one's EI and fit
        out.setdefault("per_crossing", {})[name] = {
            "EI": {q: ce["EI"][q] for q in ("mean", "sd")} if "EI" in ce else None,
            "fit_check": (ce.get("fit_check") or {}).get("verdict"),
        }
    return out


def fingerprint(args) -> str:
    spec = {
        "seed": args.seed,
        "family_seed": args.family_seed,
        "snr_db": args.snr,
        "forces": args.forces,
        "vehicle": args.vehicle,
        "smoke": args.smoke,
        "mcmc": dataclasses.asdict(SMOKE_MCMC if args.smoke else MCMC),
        "speed_sd": SPEED_SD,
        "entry_time_sd": ENTRY_SD,
        # the fluctuating-force law's resonant modes (records made before they existed are not reused)
        "resonant_modes": RESONANT_MODES if args.forces == "fluctuating" else 0,
        # the axles' fluctuations with a shared part (the same road): records made before are not reused
        "shared_road": args.forces == "fluctuating",
        # the road's band of short wavelengths through a sprung body: records made before are not reused
        "road_band": args.forces == "fluctuating" and args.vehicle == "sprung",
    }
    return hashlib.sha256(json.dumps(spec, sort_keys=True).encode()).hexdigest()[:16]


def provenance(argv: list[str], seed: int) -> dict:
    p = _provenance("cpu")
    return {"command": c.command_line(__file__, argv), "seed": seed, **p}


def run_crossing(args, argv, g: int, k: int) -> dict:
    """Simulate crossing k of girder g and analyse it both ways: its record."""
    gcfg = girder_for(args, g)
    d = draw(args.seed, g, k)
    t0 = time.perf_counter()
    data = simulate(truth_config(gcfg, d), args.snr, d["data_seed"], args.smoke)
    sim_s = time.perf_counter() - t0
    ei = gcfg.beam.EI
    rec = {
        "schema": RECORD_SCHEMA,
        "fingerprint": fingerprint(args),
        "girder": g,
        "crossing": k,
        "girder_config": {
            "length": gcfg.beam.length,
            "EI": ei,
            "mass_per_length": gcfg.beam.mass_per_length,
            "sample_rate": gcfg.data.sample_rate,
            "prior_EI_median": gcfg.prior.EI_median,
        },
        "truth_and_stated": d,
        "n_data": len(data),
        "simulate_s": sim_s,
        "snr_db": args.snr,
    }
    log.info("crossing g%d-c%d: simulated in %.0f s, %d samples", g, k, sim_s, len(data))
    for name, declared in (("declared", True), ("today", False)):
        cfg = stated_config(gcfg, d, declared, args.forces, args.vehicle)
        rec[name] = analyse(data, cfg, ei, args.snr, d["data_seed"] % 1000, args.smoke)
        log.info(
            "  %s: z %+.2f hit %s fit %s in %.0f s", name, rec[name]["z"], rec[name]["hit"],
            rec[name]["fit_check"]["verdict"], rec[name]["runtime_s"],
        )  # fmt: skip
    rec["provenance"] = provenance(argv, args.seed)
    return rec


# -------------------------------------------------------------------------------------- summaries
def summarise(records: list[dict], which: str) -> dict:
    """Hits against the binomial region, the fit check's verdicts and the z distribution of one analysis
    ("declared" or "today") over the records."""
    rs = [r[which] for r in records if which in r]
    n = len(rs)
    if not n:
        return {"n": 0}
    hits = sum(bool(r["hit"]) for r in rs)
    lo, hi = binomial_acceptance(n, LEVEL, FALSE_FAILURE)
    verdicts = [r["fit_check"]["verdict"] for r in rs]
    z = np.array([r["z"] for r in rs], float)
    return {
        "n": n,
        "hits": hits,
        "region": [lo, hi],
        "calibrated": bool(lo <= hits <= hi),
        "fits": verdicts.count("fits"),
        "misfit": verdicts.count("misfit"),
        "fits_rate": verdicts.count("fits") / n,
        "misfit_rate": verdicts.count("misfit") / n,
        "z": {
            "mean": float(z.mean()),
            "sd": float(z.std(ddof=1)) if n > 1 else None,
            "min": float(z.min()),
            "max": float(z.max()),
        },
        # converged: every check of the analysis met (the sampler's, and the linearisation's where used);
        # records written before the verdict carried the linearisation's check have no "problems" and
        # are counted apart, not as converged
        "converged": sum(r.get("converged") is True and "problems" in r for r in rs),
        "verdict_missing": sum("problems" not in r for r in rs),
        "linearisation_failed": sum(
            (r.get("linearisation_check") or {}).get("passed") is False for r in rs
        ),
        "importance_sampled": sum("importance" in r for r in rs),
        "runtime_s": {
            "median": float(np.median([r["runtime_s"] for r in rs])),
            "max": float(max(r["runtime_s"] for r in rs)),
        },
    }


#: a nuisance's posterior "holds" its truth within this many of its posterior sds
NUISANCE_Z = 2.0


def nuisance_z(rec: dict, name: str) -> float | None:
    """(posterior mean - truth) / posterior sd of a declared nuisance ("speed", "entry_time",
    "body_frequency", "damping_ratio") of one record; None where the record lacks it."""
    e, truth = (rec.get("declared") or {}).get(name), rec["truth_and_stated"].get(name)
    if not e or truth is None or not e.get("sd"):
        return None
    return (e["mean"] - truth) / e["sd"]


def nuisances(records: list[dict]) -> dict:
    """How the declared analysis' nuisances sit against their truths, and whether EI's misses follow them:
    each nuisance's rms z; EI's rms z over the crossings whose speed posterior holds the truth within
    NUISANCE_Z sds and over those where it does not; the correlation of EI's z with the speed's z."""
    rows = [
        (r["declared"]["z"], *(nuisance_z(r, k) for k in ("speed", "entry_time", "body_frequency")))
        for r in records
        if "declared" in r
    ]
    rows = [row for row in rows if row[1] is not None and row[2] is not None]
    if len(rows) < 2:
        return {"n": len(rows)}
    z = np.array([[np.nan if v is None else v for v in row] for row in rows], float)

    def rms(v: np.ndarray) -> float | None:
        v = v[np.isfinite(v)]
        return float(np.sqrt(np.mean(v * v))) if v.size else None

    near = np.abs(z[:, 1]) <= NUISANCE_Z
    return {
        "n": len(rows),
        "rms_z": {
            "EI": rms(z[:, 0]),
            "speed": rms(z[:, 1]),
            "entry_time": rms(z[:, 2]),
            "body_frequency": rms(z[:, 3]),
        },
        "speed_within": int(near.sum()),
        "EI_rms_z_speed_within": rms(z[near, 0]),
        "EI_rms_z_speed_beyond": rms(z[~near, 0]),
        "corr_EI_speed": float(np.corrcoef(z[:, 0], z[:, 1])[0, 1]),
    }


def summary(doc: dict, planned: int) -> dict:
    recs = doc["records"]
    a, b = summarise(recs, "declared"), summarise(recs, "today")
    out = {
        "planned": planned,
        "done": len(recs),
        "partial": len(recs) < planned,
        "declared": a,
        "today": b,
        "declared_nuisances": nuisances(recs),
    }
    if a.get("n"):
        out["declared_fits_target_met"] = a["fits_rate"] >= FITS_TARGET
    if b.get("n"):
        out["today_misfit_target_met"] = b["misfit_rate"] >= MISFIT_TARGET
    return out


# ------------------------------------------------------------------------------------- the study
def record_path(out: Path, g: int, k: int) -> Path:
    return out / "crossings" / f"g{g}-c{k}.json"


def load_record(path: Path, key: str) -> dict | None:
    if not path.is_file():
        return None
    try:
        rec = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError):
        return None
    return rec if rec.get("schema") == RECORD_SCHEMA and rec.get("fingerprint") == key else None


def run_study(args, argv) -> dict:
    out = Path(args.out)
    key = fingerprint(args)
    wanted = [(g, k) for k in range(args.crossings) for g in range(args.girders)]
    if args.only_girder is not None:
        wanted = [(g, k) for g, k in wanted if g == args.only_girder]
    if args.reverse:
        wanted.reverse()
    records = []
    t_start = time.monotonic()
    for g, k in wanted:
        p = record_path(out, g, k)
        rec = load_record(p, key) if args.resume else None
        if rec is None:
            if args.max_minutes and time.monotonic() - t_start > 60 * args.max_minutes:
                log.info("crossings: --max-minutes reached; the study is partial")
                break
            rec = run_crossing(args, argv, g, k)
            c.write_json(p, rec)
        records.append(rec)
        write_study(out, args, argv, key, len(wanted))
    return write_study(out, args, argv, key, len(wanted))


def existing(out: Path, key: str) -> list[dict]:
    recs = [load_record(p, key) for p in sorted((out / "crossings").glob("g*-c*.json"))]
    return sorted((r for r in recs if r), key=lambda r: (r["girder"], r["crossing"]))


def write_study(out: Path, args, argv, key: str, planned: int) -> dict:
    path = out / "crossings" / "study.json"
    old = json.loads(path.read_text(encoding="utf-8")) if path.is_file() else {}
    if old.get("fingerprint") != key:
        old = {}
    doc = {
        "schema": STUDY_SCHEMA,
        "fingerprint": key,
        "settings": {
            "seed": args.seed,
            "family_seed": args.family_seed,
            "snr_db": args.snr,
            "forces": args.forces,
            "vehicle": args.vehicle,
            "speed_sd": SPEED_SD,
            "entry_time_sd": ENTRY_SD,
            "stated_damping": STATED_DAMPING,
            "mcmc": dataclasses.asdict(SMOKE_MCMC if args.smoke else MCMC),
        },
        "records": existing(out, key),
        "joint": None,
        "exeter_check": old.get("exeter_check"),
        "runs": [*old.get("runs", []), provenance(argv, args.seed)][-10:],
    }
    for k in sorted(k for k in old if k.startswith("joint") and old[k]):
        doc[k] = joint_ratio(old[k], doc["records"])
    doc["summary"] = summary(doc, max(planned, old.get("summary", {}).get("planned", 0)))
    c.write_json(path, {k: v for k, v in doc.items() if k != "records"} | {"records": [
        {"id": f"g{r['girder']}-c{r['crossing']}", **{k: r.get("provenance", {}).get(k) for k in (
            "git_commit", "git_dirty")}} for r in doc["records"]]})  # fmt: skip
    write_page(out, doc)
    return doc


def joint_key(g: int) -> str:
    """study.json's key of girder g's joint analysis ("joint" for girder 0, as before)."""
    return "joint" if g == 0 else f"joint_g{g}"


def run_joint(args, argv) -> dict:
    """The first `args.joint` crossings of girder `args.joint_girder` in one analysis (declared), against
    one crossing's sd."""
    from bayespinn.config import Crossing
    from bayespinn.data.measurements import Measurements

    g = args.joint_girder
    gcfg = girder_for(args, g)
    parts, tables = [], []
    for k in range(args.joint):
        d = draw(args.seed, g, k)
        data = simulate(truth_config(gcfg, d), args.snr, d["data_seed"], args.smoke)
        parts.append(dataclasses.replace(data, crossing=np.full(len(data), f"c{k}")))
        v = stated_config(gcfg, d, True, args.forces, args.vehicle).vehicle
        tables.append(Crossing(f"c{k}", v))
    cat = {
        f: np.concatenate([getattr(p, f) for p in parts])
        for f in ("x", "t", "value", "kind", "y", "sensor", "value_true", "crossing")
    }
    data = Measurements(**cat)
    cfg = stated_config(gcfg, draw(args.seed, g, 0), True, args.forces, args.vehicle)
    cfg = dataclasses.replace(cfg, crossings=tuple(tables))
    e = analyse(data, cfg, gcfg.beam.EI, args.snr, 0, args.smoke)
    return {"crossings": args.joint, "girder": g, **e, "provenance": provenance(argv, args.seed)}


def joint_ratio(joint: dict, records: list[dict]) -> dict:
    """The joint analysis' EI sd against the median sd of the same girder's crossings analysed one at a
    time (declared), over those of its crossings analysed so far."""
    one = [
        r["declared"]["EI"]["sd"]
        for r in records
        if r["girder"] == joint.get("girder", 0)
        and r["crossing"] < joint["crossings"]
        and "declared" in r
    ]
    med = float(np.median(one)) if one else None
    return {
        **joint,
        "one_crossing_n": len(one),
        "one_crossing_sd_median": med,
        "sd_ratio": joint["EI"]["sd"] / med if med else None,
        "sd_ratio_target_met": (joint["EI"]["sd"] / med <= SD_RATIO_TARGET) if med else None,
    }


def exeter_check() -> dict:
    """`bayespinn run` of the exeter-snr20-seed11 record's command, modal only, against its modal EI."""
    import subprocess
    import tempfile
    import time

    root = Path(__file__).resolve().parents[1]
    summ = json.loads((root / "reports/records/exeter-snr20-seed11/summary.json").read_text())
    ref = summ["methods"]["modal_mcmc"]["EI"]
    with tempfile.TemporaryDirectory() as tmp:
        cmd = ["bayespinn", "run", "--snr", "20", "--method", "modal", "--seed", "11",
               "--out", tmp, "--quiet"]  # fmt: skip
        t0 = time.perf_counter()
        subprocess.run([sys.executable, "-m", "bayespinn", *cmd[1:]], check=True, cwd=root)
        runtime = time.perf_counter() - t0
        new = json.loads((Path(tmp) / "summary.json").read_text())["methods"]["modal_mcmc"]["EI"]
    shift = (new["mean"] - ref["mean"]) / ref["sd"]
    return {
        "command": " ".join(cmd[:-3] + ["--out", "<dir>", "--quiet"]),
        "record_mean": ref["mean"],
        "record_sd": ref["sd"],
        "fresh_mean": new["mean"],
        "fresh_sd": new["sd"],
        "shift_in_record_sd": shift,
        "within": abs(shift) <= 0.3,
        "runtime_s": runtime,
        **c.replicate_provenance(),
    }


# ------------------------------------------------------------------------------------------ page
def write_page(out: Path, doc: dict) -> None:
    from bayespinn.report.document import Alert, Heading, Paragraph, table

    s = doc["summary"]
    st = doc["settings"]
    blocks = [Heading("Realistic crossings: the modal reference against the truth", 1)]
    if s["partial"]:
        blocks.append(
            Alert(f"Partial: {s['done']} of {s['planned']} planned crossings analysed so far.")
        )
    blocks.append(
        Paragraph(
            "Crossings by the independent simulator: the strain case's four-axle truck, each axle a "
            "sprung mass, on class A and B roads, at "
            f"{st['snr_db']:g} dB on the four gauges; the speed stated within +-1.5 % and the entry "
            "time within +-0.1 s of the truth. (a) declared: speed_sd "
            f"{st['speed_sd']:.4f}, entry_time_sd {st['entry_time_sd']:.4f} s, damping inferred, "
            f"axle forces {st['forces']}, vehicle model {st.get('vehicle', 'forces')} (each axle's body "
            "on a suspension whose bounce frequency and damping are inferred about 2.5 Hz and 0.1); (b) "
            "today: nothing declared."
        )
    )
    if st["forces"] == "constant":
        blocks.append(
            Paragraph(
                "In this run (a) kept constant axle forces: [model] axle_forces = 'fluctuating' was "
                "not used, so (a) declares the speed, the entry time and the damping only."
            )
        )
    rows = []
    for name, label in (("declared", "(a) declared"), ("today", "(b) today's model")):
        a = s[name]
        if not a.get("n"):
            continue
        rows.append(
            [
                label,
                str(a["n"]),
                f"{a['hits']} [{a['region'][0]}, {a['region'][1]}]",
                c.yes_no(a["calibrated"]),
                f"{a['fits']} ({100 * a['fits_rate']:.0f} %)",
                f"{a['misfit']} ({100 * a['misfit_rate']:.0f} %)",
                f"{a['z']['mean']:+.2f} / {a['z']['min']:+.2f} .. {a['z']['max']:+.2f}",
                _converged_cell(a),
                f"{a['runtime_s']['median']:.0f}",
            ]
        )
    if rows:
        blocks.append(
            table(
                [
                    "analysis",
                    "n",
                    "hits [99 % region]",
                    "calibrated",
                    "fits",
                    "misfit",
                    "z mean / range",
                    "converged",
                    "median s",
                ],
                rows,
            )  # fmt: skip
        )
        blocks.append(
            Paragraph(
                f"Targets: (a) fits on at least {100 * FITS_TARGET:.0f} %, (b) misfit on at least "
                f"{100 * MISFIT_TARGET:.0f} %. converged: the analyses that met every check of their "
                "sampler: with fluctuating forces, the linearisation's importance check against the "
                "exact likelihood, and where it fails, the adaptive importance sampling of the exact "
                "posterior that replaces it (effective sample size and Pareto k-hat of its weights"
                + (
                    f"; used on {s['declared'].get('importance_sampled', 0)} of "
                    f"{s['declared'].get('n', 0)} declared analyses"
                    if s["declared"].get("n")
                    else ""
                )
                + "); not judged: records written before the analysis recorded that check."
            )
        )
    per = []
    for r in doc["records"]:
        d = r["truth_and_stated"]
        cells = [f"g{r['girder']}-c{r['crossing']}", d["road"], f"{d['speed']:.2f}",
                 f"{100 * (d['stated_speed'] / d['speed'] - 1):+.2f}",
                 f"{d['stated_entry_time'] - d['entry_time']:+.3f}", f"{100 * d['damping_ratio']:.2f}"]  # fmt: skip
        for name in ("declared", "today"):
            e = r.get(name)
            cells += (
                [f"{e['z']:+.2f}", c.yes_no(e["hit"]), str(e["fit_check"]["verdict"])]
                if e
                else ["n/a"] * 3
            )
            if name == "declared":
                cells += [_num(nuisance_z(r, k), "+.1f") for k in ("speed", "entry_time")]
        per.append(cells)
    if per:
        blocks.append(Heading("Per crossing"))
        blocks.append(
            table(
                [
                    "crossing",
                    "road",
                    "speed m/s",
                    "stated speed %",
                    "stated entry s",
                    "damping %",
                    "(a) z",
                    "(a) hit",
                    "(a) fit",
                    "(a) speed z",
                    "(a) entry z",
                    "(b) z",
                    "(b) hit",
                    "(b) fit",
                ],
                per,
            )  # fmt: skip
        )
    nu = s.get("declared_nuisances") or {}
    if nu.get("n", 0) >= 2:
        rz = nu["rms_z"]
        blocks.append(Heading("What the declared misses share"))
        blocks.append(
            Paragraph(
                f"Over {nu['n']} declared analyses, the rms z against the truth (1 for a calibrated "
                f"posterior): EI {_num(rz['EI'])}, speed {_num(rz['speed'])}, entry time "
                f"{_num(rz['entry_time'])}, bounce frequency {_num(rz['body_frequency'])}. EI's z "
                f"correlates with the speed's by {nu['corr_EI_speed']:+.2f}. Where the speed's "
                f"posterior holds the truth within {NUISANCE_Z:g} sd ({nu['speed_within']} "
                f"crossings), EI's rms z is {_num(nu['EI_rms_z_speed_within'])}; where it does not "
                f"({nu['n'] - nu['speed_within']}), {_num(nu['EI_rms_z_speed_beyond'])}. "
                "(a) speed z, (a) entry z: the declared posterior's mean against the truth, in its sds."
            )
        )
    blocks.append(Heading("Several crossings in one analysis"))
    joints = [doc[k] for k in sorted(doc) if k.startswith("joint") and doc[k]]
    for j in joints:
        blocks.append(
            Paragraph(
                f"{j['crossings']} crossings of girder {j.get('girder', 0)} together: EI sd "
                f"{j['EI']['sd']:.4g} against the median of one crossing's over "
                f"{j.get('one_crossing_n')} of them analysed alone: ratio {_num(j.get('sd_ratio'))} "
                f"(target <= {SD_RATIO_TARGET}); the interval holds the truth: "
                f"{c.yes_no(j['hit'])} (z {j['z']:+.2f}); fit {j['fit_check']['verdict']}; "
                f"{j['runtime_s']:.0f} s."
                + (
                    f" The crossing-level error's sd (relative): {j['crossing_error']['mean']:.2e} "
                    f"(90 % {j['crossing_error']['ci90'][0]:.2e} to {j['crossing_error']['ci90'][1]:.2e})."
                    if j.get("crossing_error")
                    else ""
                )
                + (
                    " Not converged: "
                    + "; ".join(j.get("problems") or ["a sampler missed its checks"])
                    + "."
                    if j.get("converged") is False
                    else ""
                )
            )
        )
    if not joints:
        blocks.append(Paragraph("Not run yet."))
    x = doc.get("exeter_check")
    blocks.append(Heading("Nothing declared: exeter-snr20-seed11 keeps its answer"))
    if x:
        blocks.append(
            Paragraph(
                f"`{x['command']}`: modal EI mean {x['fresh_mean']:.6g} against the record's "
                f"{x['record_mean']:.6g}: {x['shift_in_record_sd']:+.3f} record sd (target within "
                f"0.3): {c.yes_no(x['within'])}."
            )
        )
    else:
        blocks.append(Paragraph("Not run yet."))
    runs = doc.get("runs") or []
    if runs:
        r = runs[-1]
        blocks.append(
            Paragraph(
                f"Last run: `{r['command']}`, {r['date']}, git {str(r.get('git_commit'))[:12]}"
                + (" (uncommitted changes)" if r.get("git_dirty") else "")
                + f", {r['machine'].get('cpu_model')}."
            )
        )
    c.write_markdown(out / "crossings.md", blocks)


def _converged_cell(a: dict) -> str:
    """The converged count, with the records that predate the verdict said apart."""
    if "converged" not in a:
        return "n/a"
    missing = a.get("verdict_missing", 0)
    return f"{a['converged']}" + (f" ({missing} not judged)" if missing else "")


def _num(v, fmt: str = ".2f") -> str:
    return "n/a" if v is None else format(v, fmt)


# ------------------------------------------------------------------------------------------ main
def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--girders", type=int, default=3)
    p.add_argument("--crossings", type=int, default=10, help="crossings per girder")
    p.add_argument("--snr", type=float, default=30.0)
    p.add_argument("--seed", type=int, default=50, help="the study's seed (every draw)")
    p.add_argument("--family-seed", type=int, default=50)
    p.add_argument("--forces", choices=("fluctuating", "constant"), default="fluctuating")
    p.add_argument(
        "--vehicle", choices=("sprung", "forces"), default="sprung",
        help="the declared analysis' vehicle model",
    )  # fmt: skip
    p.add_argument("--only-girder", type=int, default=None, help="run one girder's crossings")
    p.add_argument("--joint", type=int, default=0, help="analyse this many of a girder's together")
    p.add_argument("--joint-girder", type=int, default=0, help="the girder --joint analyses")
    p.add_argument("--exeter-check", action="store_true")
    p.add_argument("--skip-family", action="store_true", help="only --joint / --exeter-check")
    p.add_argument("--resume", action="store_true")
    p.add_argument(
        "--reverse", action="store_true",
        help="run the crossings last first: with --resume, a second process shares the study",
    )  # fmt: skip
    p.add_argument(
        "--max-minutes", type=float, default=0, help="start no crossing after this (0: no limit)"
    )
    p.add_argument("--smoke", action="store_true", help="tiny simulator and MCMC (tests)")
    p.add_argument("--out", default="reports/paper")
    return p


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser().parse_args(argv)
    c.setup_logging(False)
    out = Path(args.out)
    key = fingerprint(args)
    planned = args.girders * args.crossings
    if not args.skip_family:
        run_study(args, argv)
    path = out / "crossings" / "study.json"
    if args.joint or args.exeter_check:
        doc = json.loads(path.read_text()) if path.is_file() else {}
        if args.joint:
            doc[joint_key(args.joint_girder)] = run_joint(args, argv)
        if args.exeter_check:
            doc["exeter_check"] = exeter_check()
        doc.update(schema=STUDY_SCHEMA, fingerprint=key)
        c.write_json(path, doc)
    write_study(out, args, argv, key, planned)
    return 0


if __name__ == "__main__":
    sys.exit(main())
