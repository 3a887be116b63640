"""The file reference covers every field the loaders accept, and the page in docs is current."""

from __future__ import annotations

import copy
from pathlib import Path

import pytest

from uavmpc import scenarios
from uavmpc.apps.fileref import (
    _scenario_probes,
    known_fields,
    reference_markdown,
    reference_tables,
)
from uavmpc.config import ConfigError

DOCS = Path(__file__).parents[1] / "docs"


def test_every_field_of_every_table_has_its_description() -> None:
    tables = reference_tables()
    assert len(tables) == 19
    missing = [(t, f) for t, rows in tables.items() for f, _d, text in rows if not text]
    assert missing == []
    # a few fields each loader is known to take, where their tables are
    fields = {t: {f for f, _, _ in rows} for t, rows in tables.items()}
    assert {"radius_m", "silent_hold_s", "time_reference"} <= fields["avoidance"]
    assert {"id", "priority", "goto", "path", "trajectory", "avoidance"} <= fields["uavs[]"]
    assert {"min_altitude_m", "max_altitude_m", "box", "polygon"} <= fields["geofence"]
    assert {"k_f_n_per_radps2", "omega_max_radps"} <= fields["airframe.rotors"]


def test_the_fields_are_those_the_loader_refuses_others_than() -> None:
    # each field listed is accepted (it is in a valid file, or setting it to its own default
    # passes), and the probe field is refused: the list comes from the loader itself
    name, doc, path, _cls = _scenario_probes()[1]  # [link]
    assert name == "link"
    for field in known_fields(lambda d: scenarios.from_dict(d), doc, path):
        d = copy.deepcopy(doc)
        d["link"][field] = d["link"].get(field, 0.0)
        scenarios.from_dict(d)
    d = copy.deepcopy(doc)
    d["link"]["latency"] = 0.1  # a typo
    with pytest.raises(ConfigError, match=r"link\.latency: unknown field"):
        scenarios.from_dict(d)
    # the avoidance table is checked on load too (not first when a world is built)
    d = copy.deepcopy(doc)
    d["avoidance"] = {"radius": 5.0}
    with pytest.raises(ConfigError, match=r"avoidance\.radius: unknown field"):
        scenarios.from_dict(d)


def test_the_page_in_docs_is_current() -> None:
    assert (DOCS / "reference" / "files.md").read_text() == reference_markdown(), (
        "regenerate it: uavmpc file-reference --out docs/reference/files.md")
