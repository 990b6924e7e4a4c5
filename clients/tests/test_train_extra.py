"""The `train` extra's ranges and their two tested ends: `.venv`, locked at the newest tested
versions (clients/requirements-train.txt), and `.venv-lower`, at each range's lower bound
(clients/requirements-lower.txt). `make test` runs this file in both venvs."""

from __future__ import annotations

from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _pins(path: Path) -> dict[str, str]:
    """``name==version`` lines of a requirements file."""
    out = {}
    for line in path.read_text().splitlines():
        line = line.split("#")[0].strip()
        if "==" in line:
            name, version = line.split("==")
            out[name.strip().lower()] = version.strip()
    return out


def _train_extra() -> dict[str, object]:
    import tomllib

    from packaging.requirements import Requirement

    project = tomllib.loads((REPO / "clients" / "pyproject.toml").read_text())["project"]
    reqs = [Requirement(r) for r in project["optional-dependencies"]["train"]]
    return {r.name.lower(): r.specifier for r in reqs}


def test_the_train_extra_takes_ranges_whose_two_tested_ends_are_pinned():
    """The extra's ranges, the locked .venv (requirements-train.txt) inside them and the lower
    venv (requirements-lower.txt) at each range's lower bound."""
    from packaging.version import Version

    extra = _train_extra()
    locked = _pins(REPO / "clients" / "requirements-train.txt")
    lower = _pins(REPO / "clients" / "requirements-lower.txt")
    assert set(lower) == set(extra), "requirements-lower.txt pins every package of the extra"
    for name, spec in extra.items():
        assert not [s for s in spec if s.operator == "=="], f"{name}: a range, not a pin"
        floor = [Version(s.version) for s in spec if s.operator == ">="]
        assert floor == [Version(lower[name])], f"{name}: lower pin {lower[name]}, range {spec}"
        assert spec.contains(locked[name]), f"{name}: locked {locked[name]} outside {spec}"


def test_the_installed_trainer_is_one_tested_end_of_the_ranges():
    """The venv running the tests holds the locked versions or the lower bounds, all of one."""
    from importlib.metadata import version

    from packaging.version import Version

    installed = {name: Version(version(name)) for name in _train_extra()}
    ends = {
        label: {k: Version(v) for k, v in _pins(REPO / "clients" / f).items() if k in installed}
        for label, f in (("locked", "requirements-train.txt"), ("lower", "requirements-lower.txt"))
    }
    # torch's local build tag (+cu130) is not part of the pin
    plain = {k: Version(v.public) for k, v in installed.items()}
    assert plain in list(ends.values()), f"installed {plain}, neither end {ends}"
