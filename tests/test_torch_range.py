"""The torch versions pyproject.toml admits are the ones CI tests: its lowest and its highest."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _torch_range() -> tuple[str, str]:
    text = (ROOT / "pyproject.toml").read_text()
    m = re.search(r'"torch>=([0-9.]+),<=([0-9.]+)"', text)
    assert m, "pyproject.toml pins torch as a closed range >=LOW,<=HIGH"
    return m.group(1), m.group(2)


def test_ci_installs_both_ends_of_the_torch_range():
    low, high = _torch_range()
    ci = (ROOT / ".ci" / "run").read_text()
    installs = re.findall(r"pip install torch==([0-9.]+)", ci)
    assert installs == [low, high], installs
    # each end runs the test suite after its install
    for v in (low, high):
        after = ci[ci.index(f"torch=={v}") :].split("\n", 1)[0]
        assert "python -m pytest -q" in after, after


def test_the_range_is_ordered():
    low, high = (tuple(int(p) for p in v.split(".")) for v in _torch_range())
    assert low < high
