"""Executors: results are a function of the seed only, whatever runs them."""

import dataclasses
import importlib.util

import pytest

from bayespinn.config import preset
from bayespinn.executor import Executor
from bayespinn.options import RunOptions
from bayespinn.uq.coverage import coverage_study
from bayespinn.uq.sampler import MCMCSettings

SMALL = RunOptions(
    profile="smoke", mcmc=MCMCSettings(n_walkers=8, n_groups=2, min_steps=250, tau_factor=5.0)
)


def _strip(res):
    return [(r["hit"], r["rel_error_pct"], r["interval"]) for r in res["records"]]


def _study(executor):
    return coverage_study(
        "modal", preset(), 10.0, replicates=4, seed=3, opts=SMALL, executor=executor, progress=False
    )


def _warm_parent_cache():
    """Compute the FE crossing in this process with two BLAS threads first: forked workers inherit the
    cache, Ray workers do not, so this is the situation in which a thread-dependent result would show
    (it did in CI before the FE solve was pinned to one thread)."""
    from threadpoolctl import threadpool_limits

    from bayespinn.physics.fem import solve_crossing

    cfg = preset()
    with threadpool_limits(2):
        solve_crossing(cfg.beam, cfg.vehicle)


def test_fe_solution_does_not_depend_on_blas_threads():
    from threadpoolctl import threadpool_limits

    from bayespinn.physics.fem import FEBeam

    cfg = preset()
    T = cfg.vehicle.duration(cfg.beam.length)
    out = []
    for n in (1, 2):
        with threadpool_limits(n):
            out.append(FEBeam(cfg.beam).solve(cfg.vehicle, T).U)
    assert (out[0] == out[1]).all()


def test_local_results_do_not_depend_on_workers():
    _warm_parent_cache()
    one = _study(Executor("local", workers=1))
    two = _study(Executor("local", workers=2))
    assert _strip(one) == _strip(two)


def test_coverage_resumes_from_its_checkpoint(tmp_path, monkeypatch):
    """An interrupted study keeps its finished replicates; the same study started again runs only the rest
    and gives the records an uninterrupted one gives. A different study does not reuse them."""
    import bayespinn.uq.coverage as cov

    ck = tmp_path / "c.partial.jsonl"
    full = _study(Executor("local", workers=1))
    calls = []
    real = cov.run_replicate

    def failing(task):
        calls.append(task.index)
        if task.index == 2:
            raise KeyboardInterrupt  # the user stops the study during replicate 2
        return real(task)

    monkeypatch.setattr(cov, "run_replicate", failing)
    with pytest.raises(KeyboardInterrupt):
        coverage_study(
            "modal",
            preset(),
            10.0,
            replicates=4,
            seed=3,
            opts=SMALL,
            progress=False,
            executor=Executor("local", workers=1),
            checkpoint=ck,
        )
    assert len(ck.read_text().splitlines()) == 3  # header + replicates 0 and 1
    monkeypatch.setattr(cov, "run_replicate", lambda t: (calls.append(t.index), real(t))[1])
    calls.clear()
    res = coverage_study(
        "modal",
        preset(),
        10.0,
        replicates=4,
        seed=3,
        opts=SMALL,
        progress=False,
        executor=Executor("local", workers=1),
        checkpoint=ck,
    )
    assert calls == [2, 3] and res["resumed_replicates"] == 2
    assert _strip(res) == _strip(full)
    # another seed is another study: nothing is reused
    calls.clear()
    other = coverage_study(
        "modal",
        preset(),
        10.0,
        replicates=2,
        seed=4,
        opts=SMALL,
        progress=False,
        executor=Executor("local", workers=1),
        checkpoint=ck,
    )
    assert calls == [0, 1] and other["resumed_replicates"] == 0


def test_coverage_resumes_from_an_earlier_study_file(tmp_path, monkeypatch):
    """A study carried over two sessions: the first writes 2 replicates to its file, the second asks for 4
    with that file to resume from, runs replicates 2 and 3 only and gives the records of one uninterrupted
    study. A file of another study (other seed), or one without a fingerprint, gives nothing."""
    import json

    import bayespinn.uq.coverage as cov

    def run(n, seed=3, resume_from=None):
        return coverage_study(
            "modal",
            preset(),
            10.0,
            replicates=n,
            seed=seed,
            opts=SMALL,
            progress=False,
            executor=Executor("local", workers=1),
            resume_from=resume_from,
        )

    first = tmp_path / "first.json"
    first.write_text(json.dumps(run(2)), encoding="utf-8")
    calls = []
    real = cov.run_replicate
    monkeypatch.setattr(cov, "run_replicate", lambda t: (calls.append(t.index), real(t))[1])
    res = run(4, resume_from=first)
    assert calls == [2, 3] and res["resumed_replicates"] == 2
    assert _strip(res) == _strip(_study(Executor("local", workers=1)))
    calls.clear()
    assert run(2, seed=4, resume_from=first)["resumed_replicates"] == 0 and calls == [0, 1]
    old = json.loads(first.read_text(encoding="utf-8"))
    del old["fingerprint"]
    first.write_text(json.dumps(old), encoding="utf-8")
    calls.clear()
    assert run(2, resume_from=first)["resumed_replicates"] == 0 and calls == [0, 1]


def test_a_pinn_study_is_not_resumed_across_a_change_of_its_model_constants(monkeypatch):
    """The PINNs' pseudo-observation and weight-prior factors live in code, not in the configuration: a
    study whose replicates were made with another factor is another study (its key differs), so resuming
    cannot pool replicates of two models. The reference's key does not depend on them."""
    from bayespinn.uq import coverage as cov
    from bayespinn.uq import girder_lastlayer, lastlayer

    def keys():
        return {
            m: cov.fingerprint(
                m, preset(), 10.0, 0, 0.9, "fixed", cov.study_options(m, 10.0, SMALL)
            )
            for m in ("ensemble", "bpinn", "modal")
        }

    before = keys()
    assert keys() == before  # the same code, the same keys
    for module, name in (
        (lastlayer, "PDE_SD_FACTOR"),
        (lastlayer, "WEIGHT_PRIOR_FACTOR"),
        (girder_lastlayer, "GIRDER_PDE_SD_FACTOR"),
    ):
        with monkeypatch.context() as mp:
            mp.setattr(module, name, getattr(module, name) * 3)
            after = keys()
        assert after["ensemble"] != before["ensemble"] and after["bpinn"] != before["bpinn"], name
        assert after["modal"] == before["modal"], name


def _ensemble(executor, seed=3):
    import numpy as np

    from bayespinn import methods
    from bayespinn.data.synthetic import simulate

    cfg = preset()
    data = simulate(cfg, 20.0, seed=1)
    post = methods.build(
        "ensemble", RunOptions(profile="smoke", members=3, device="cpu", executor=executor)
    ).infer(data, cfg, seed=seed)
    assert post.diagnostics["training"] == "one task per member"
    return post.info["member_EI"], post.info["member_sigma_mode"], np.asarray(post.EI).ravel()


def test_ensemble_members_do_not_depend_on_workers():
    one = _ensemble(Executor("local", workers=1))
    two = _ensemble(Executor("local", workers=2))
    assert one[0] == two[0] and one[1] == two[1] and (one[2] == two[2]).all()
    # negative control: the comparison sees a different seed
    assert _ensemble(Executor("local", workers=2), seed=4)[0] != two[0]


def test_sweep_levels_do_not_depend_on_workers(tmp_path):
    """Levels are executor tasks with the ensemble's members run inside them: same numbers, same files."""
    import json

    from bayespinn.sweep import sweep

    opts = dataclasses.replace(SMALL, members=2, progress=False)
    docs = []
    for w in (1, 2):
        out = tmp_path / f"w{w}"
        docs.append(
            sweep(
                preset(),
                levels=[None, 20.0],
                methods=["modal", "ensemble"],
                seed=0,
                out=out,
                opts=dataclasses.replace(opts, executor=Executor("local", workers=w)),
            )
        )
        assert {p.name for p in out.iterdir()} >= {"snrclean", "snr20", "sweep.json", "report.html"}
        assert json.loads((out / "snr20" / "summary.json").read_text())["snr_db"] == 20.0

    def means(doc):
        return [
            (lv["snr_db"], {k: m["EI"]["mean"] for k, m in lv["methods"].items()})
            for lv in doc["levels"]
        ]

    assert means(docs[0]) == means(docs[1])
    assert [lv["snr_db"] for lv in docs[0]["levels"]] == [None, 20.0]


def test_bench_ensemble_reports_what_the_toolkit_uses():
    from bayespinn.pinn.bench import bench_ensemble

    r = bench_ensemble(
        members=2, points=40, repeats=1, warmup=1, parallel_steps=2, parallel_rounds=3, workers=2
    )
    assert r["together"] == "parallel processes" and r["workers"] == 2
    assert r["speedup"] == r["parallel_speedup"] == r["sequential_s"] / r["parallel_s"]
    # the compared times are the medians of the interleaved rounds
    assert (
        r["parallel_rounds"] == 3
        and len(r["sequential_rounds_s"]) == len(r["parallel_rounds_s"]) == 3
    )
    assert (
        r["sequential_s"] == sorted(r["sequential_rounds_s"])[1]
        and r["parallel_s"] == sorted(r["parallel_rounds_s"])[1]
    )
    assert r["batched_speedup"] == r["sequential_ms_per_epoch"] / r["batched_ms_per_epoch"]


def test_bench_many_networks_counts_networks_times_steps():
    from bayespinn.pinn.bench_networks import bench_many_networks

    r = bench_many_networks(counts=(1, 3), points=30, width=8, depth=2, seconds=0.0, min_steps=2)
    one, three = r["rows"]
    assert one["networks"] == 1 and three["networks"] == 3 and one["ratio_vs_one"] == 1.0
    assert three["networks_steps_per_s"] == pytest.approx(3 * 2 / (2 * three["ms_per_step"] / 1e3))
    assert three["ratio_vs_one"] == three["networks_steps_per_s"] / one["networks_steps_per_s"]


def test_bad_executor_is_input_error():
    from bayespinn.errors import InputError

    with pytest.raises(InputError):
        Executor("dask")


@pytest.mark.skipif(
    importlib.util.find_spec("ray") is None,
    reason="Ray is not installed (pip install 'bayespinn[ray]')",
)
def test_ray_matches_local():
    import ray

    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False, ignore_reinit_error=True)
    try:
        _warm_parent_cache()
        local = _study(Executor("local", workers=2))
        remote = _study(Executor("ray"))
        assert _strip(local) == _strip(remote)
        # an ensemble's members as Ray tasks: the same members as in the local pool
        a, b = _ensemble(Executor("local", workers=2)), _ensemble(Executor("ray"))
        assert a[0] == b[0] and a[1] == b[1] and (a[2] == b[2]).all()
    finally:
        ray.shutdown()


def test_replicate_options_are_picklable():
    import pickle

    opts = dataclasses.replace(SMALL, executor=Executor())
    assert pickle.loads(pickle.dumps(opts)) == opts


def test_ray_tasks_ask_for_a_gpu_share_only_when_training_on_cuda():
    from bayespinn.executor import GPU_FRACTION, task_resources

    assert task_resources("cpu") == {"num_cpus": 1} == task_resources(None)
    assert task_resources("cuda") == {"num_cpus": 1, "num_gpus": GPU_FRACTION}
    assert task_resources("cuda:1")["num_gpus"] == GPU_FRACTION


def _small_modal_study(n, **kw):
    """A modal coverage study of n replicates at 10 dB: small settings, one worker."""
    return coverage_study(
        "modal",
        preset(),
        10.0,
        replicates=n,
        seed=3,
        opts=SMALL,
        progress=False,
        executor=Executor("local", workers=1),
        **kw,
    )


def test_coverage_resume_keeps_other_commits_and_counts_them(tmp_path):
    """A resumed study keeps replicates whatever commit computed them: each record names its own commit,
    and the study counts the replicates of each (`commits`), so its page can say which code contributed."""
    import json

    from bayespinn.provenance import code_commit, short_commit

    first = tmp_path / "first.json"
    doc = _small_modal_study(2)
    today = short_commit(code_commit()["commit"], code_commit()["dirty"])
    assert doc["commits"] == {today: 2}
    assert all("git_commit" in r and "code_version" not in r for r in doc["records"])
    prov = doc["provenance"]  # the file's own: command, commit, dirty flag, date, packages, machine
    assert {"command", "git_commit", "git_dirty", "date", "versions", "machine"} <= set(prov)
    assert prov["machine"]["cpu_model"] and prov["versions"]["numpy"]
    assert doc["config"]["beam"]["EI"] == preset().beam.EI and doc["seed"] == 3
    doc["records"][0]["git_commit"] = "0123456789abcdef"  # as if computed at an older commit
    doc["records"][0]["git_dirty"] = False
    first.write_text(json.dumps(doc), encoding="utf-8")
    resumed = _small_modal_study(3, resume_from=first)
    assert resumed["resumed_replicates"] == 2
    assert resumed["records"][0] == doc["records"][0]  # kept as it was, not re-run
    assert resumed["commits"] == dict(sorted({"0123456789ab": 1, today: 2}.items()))


def _torn_checkpoint(path, key: str, rec: dict) -> str:
    """The checkpoint an interrupted run leaves: its header, one finished replicate, a line cut short."""
    import json

    text = json.dumps({"fingerprint": key}) + "\n" + json.dumps(rec) + "\n" + '{"index": 2, "hi'
    path.write_text(text, encoding="utf-8")
    return text


def test_a_study_stopped_before_any_replicate_leaves_the_checkpoint_as_it_was(
    tmp_path, monkeypatch
):
    """Opening a checkpoint writes nothing: a study that fails (bad input found by a replicate, a crash)
    before it finishes a replicate leaves the checkpoint byte for byte as it found it, so the resumed
    replicates of an earlier file are not written into it and the next run starts from the same state.
    Once a replicate finishes, the checkpoint holds the resumed ones, the new one, and no torn line."""
    import json

    import bayespinn.uq.coverage as cov
    from bayespinn.errors import InputError

    first = tmp_path / "first.json"
    doc = _small_modal_study(2)
    only0 = {**doc, "records": doc["records"][:1]}
    first.write_text(json.dumps(only0), encoding="utf-8")
    ck = tmp_path / "study.json.partial.jsonl"
    before = _torn_checkpoint(ck, doc["fingerprint"], doc["records"][1])

    def refuse(task):
        raise InputError("data", task.index, "a dataset this method accepts")

    monkeypatch.setattr(cov, "run_replicate", refuse)
    with pytest.raises(InputError):
        _small_modal_study(3, resume_from=first, checkpoint=ck)
    assert ck.read_text(encoding="utf-8") == before
    monkeypatch.undo()
    res = _small_modal_study(3, resume_from=first, checkpoint=ck)
    assert res["resumed_replicates"] == 2 and [r["index"] for r in res["records"]] == [0, 1, 2]
    lines = ck.read_text(encoding="utf-8").splitlines()
    assert json.loads(lines[0]) == {"fingerprint": doc["fingerprint"]}
    assert sorted(json.loads(x)["index"] for x in lines[1:]) == [0, 1, 2]


def test_coverage_datasets_are_independent_across_snr_and_shared_across_methods():
    """Replicate i at 10 dB and at 30 dB draws different points and noise; two methods at one level see the
    same dataset (the pairing of each PINN posterior with the reference rests on it)."""
    import numpy as np

    from bayespinn.data.synthetic import simulate
    from bayespinn.uq.coverage import replicate_seed

    cfg = preset()
    a, b = (simulate(cfg, s, replicate_seed(0, s, 5)) for s in (10.0, 30.0))
    assert not np.allclose(a.x, b.x) and not np.allclose(a.t, b.t)
    again = simulate(cfg, 10.0, replicate_seed(0, 10.0, 5))
    np.testing.assert_array_equal(a.value, again.value)
    assert not np.allclose(simulate(cfg, 10.0, replicate_seed(0, 10.0, 6)).x, a.x)


def test_bench_run_breaks_the_quick_start_down_by_method():
    """`bench --run`: the quick start's analysis (here at the smoke profile), its wall time and each method's
    share; the shares cannot exceed the wall time; then the time to write its run folder (the report)."""
    from bayespinn.bench import bench_run

    r = bench_run(device="cpu", progress=False, profile="smoke")
    assert r["profile"] == "smoke" and r["snr_db"] == 10.0 and r["seed"] == 0
    assert set(r["time_breakdown_s"]) == {"modal_mcmc", "ensemble", "bpinn"}
    walls = [v["wall"] for v in r["time_breakdown_s"].values()]
    assert all(w > 0 for w in walls) and sum(walls) <= r["wall_s"]
    assert r["report_s"] > 0


def _grad_of_cube(x: float) -> float:
    """d(x^3)/dx by autograd, in whatever process runs it (a pool worker here)."""
    import torch

    v = torch.tensor(x, dtype=torch.float64, requires_grad=True)
    (v**3).backward()
    return float(v.grad)


def test_pool_workers_run_autograd_after_the_parent_did():
    """Torch refuses autograd in a forked child once the parent's autograd engine started its threads (for
    CUDA in every version; from torch 2.14 also after a torch.compile'd backward on the CPU, as `bench`
    runs one): the local pool must start its workers some other way. The parent differentiates (compiled
    where torch.compile works here), then two workers differentiate; with a fork-based pool this fails on
    torch 2.14.1 with "Unable to handle autograd's threading in combination with fork-based
    multiprocessing"."""
    import torch

    from bayespinn.executor import _context

    x = torch.ones(8, requires_grad=True)
    try:
        loss = torch.compile(lambda a: (a.sin() ** 2).sum())(x)
    except Exception:  # noqa: BLE001 - no compiler in this installation: plain autograd
        loss = (x.sin() ** 2).sum()
    loss.backward()
    assert torch.allclose(x.grad, torch.sin(2 * x.detach()))
    assert _context().get_start_method() in ("forkserver", "spawn")
    out = Executor("local", workers=2).map(_grad_of_cube, [1.0, 2.0, 3.0, 4.0], progress=False)
    assert out == [3.0, 12.0, 27.0, 48.0]
