"""What every posterior file must give ArviZ users (the contract's InferenceData groups)."""

from __future__ import annotations

import numpy as np

SAMPLE_STATS = {
    "emcee": {"lp", "acceptance"},
    "nuts": {"lp", "diverging", "step_size", "tree_depth"},
}


def check_inference_data(path, data, sampler: str | None) -> None:
    """Open a posterior_<key>.nc and call az.summary, az.plot_trace and az.plot_ppc on it."""
    import arviz as az
    import matplotlib.pyplot as plt

    idata = az.from_netcdf(path)
    groups = set(idata.groups())
    assert {"posterior", "observed_data", "posterior_predictive"} <= groups, groups
    np.testing.assert_array_equal(idata.observed_data["y"].values, data.value)
    pp = idata.posterior_predictive["y"].values
    assert pp.shape[-1] == len(data) and np.isfinite(pp).all()
    # the predictive spreads around the data like the noise does, not orders of magnitude off
    resid = pp.mean(axis=(0, 1)) - data.value
    assert np.sqrt(np.mean(resid**2)) < 5 * np.std(data.value)
    if sampler is None:
        assert "sample_stats" not in groups
    else:
        assert SAMPLE_STATS[sampler] <= set(idata.sample_stats.data_vars)
        assert idata.sample_stats["lp"].shape == idata.posterior["EI"].shape
    s = az.summary(idata, var_names=["EI", "sigma"])
    assert list(s.index) == ["EI", "sigma"]
    az.plot_trace(idata, var_names=["EI"])
    az.plot_ppc(idata, num_pp_samples=20)
    plt.close("all")
