"""The documentation site builds with warnings as errors, and what getting-started says of its
first scenario is what that scenario does."""

from __future__ import annotations

import re
import subprocess
import sys
import tomllib
from pathlib import Path

from uavmpc import scenarios
from uavmpc.drivers.world import World
from uavmpc.scenarios.run import RunSpec

ROOT = Path(__file__).parents[1]


def test_mkdocs_build_strict(tmp_path: Path) -> None:
    run = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir",
                          str(tmp_path / "site")], cwd=ROOT, capture_output=True, text=True,
                         timeout=300, env={"NO_MKDOCS_2_WARNING": "1", "PATH": ""})
    assert run.returncode == 0, run.stderr[-3000:]
    for page in ("index.html", "getting-started/index.html", "reference/files/index.html",
                 "reference/api/index.html", "view/index.html"):
        assert (tmp_path / "site" / page).stat().st_size > 1000, page
    api = (tmp_path / "site" / "reference/api/index.html").read_text()
    assert "OnboardStack" in api and "scene_update" in api  # from the docstrings


def test_the_getting_started_scenario_does_what_the_page_says() -> None:
    page = (ROOT / "docs" / "getting-started.md").read_text()
    toml = re.search(r"```toml\n(.*?)```", page, re.S).group(1)
    sc = scenarios.from_dict(tomllib.loads(toml), "crossing")
    res = World(RunSpec(sc, seed=0)).run()
    assert not res.collisions and res.min_distance_m.min() > 2.0
    s = res.summary().uavs
    assert "`north` climbs 3 m while `east` passes" in page
    assert s["north"].max_z_offset_m == 3.0 and s["east"].max_z_offset_m == 0.0
    assert s["north"].reached_goal and s["east"].reached_goal
