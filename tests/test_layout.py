"""The package's import arrows point one way (docs/architecture.md): stages, then the per-UAV
program, then the drivers, then the applications; no circle between packages.

Every ``import`` in the package is read from the source, including the lazy ones inside
functions, which is where a circle would otherwise hide.
"""

import ast
from pathlib import Path

import uavmpc

ROOT = Path(uavmpc.__file__).parent

#: Each unit of the package (a top-level module or package) and its tier; a unit may import
#: units of its own tier or below, never above.
TIERS: dict[str, int] = {
    "config": 0, "jit": 0, "data": 0,
    "reference": 1, "solvers": 1, "plant": 1, "estimation": 1,
    "tracker": 2, "control": 2, "comms": 2, "missions": 2, "geofence": 2,
    "avoidance": 3,
    "onboard": 4,
    "scenarios": 5, "log": 5, "view": 5,
    "drivers": 6,
    "apps": 7,
}


def _unit(module: str) -> str | None:
    """The unit of ``uavmpc.x.y`` (``x``), or None for ``uavmpc`` itself."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else None


def _imports() -> dict[str, set[str]]:
    """unit -> the units it imports."""
    graph: dict[str, set[str]] = {}
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT).with_suffix("")
        if rel.parts == ("__init__",):
            continue
        unit = rel.parts[0]
        own = graph.setdefault(unit, set())
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module]
            for name in names:
                if name.startswith("uavmpc."):
                    target = _unit(name)
                    if target is not None and target != unit:
                        own.add(target)
    return graph


def test_every_unit_has_a_tier() -> None:
    units = {p.stem if p.is_file() else p.name for p in ROOT.iterdir()
             if (p.suffix == ".py" and p.stem != "__init__")
             or (p.is_dir() and (p / "__init__.py").exists())}
    assert units == set(TIERS), "a new module or package needs its place in TIERS"


def test_imports_point_down_the_tiers() -> None:
    upward = [(u, t) for u, targets in _imports().items() for t in targets
              if TIERS[t] > TIERS[u]]
    assert upward == [], f"imports pointing up the tiers: {upward}"


def test_no_circle_between_units() -> None:
    graph = _imports()
    state: dict[str, int] = {}

    def visit(u: str, path: list[str]) -> None:
        state[u] = 1
        for t in sorted(graph.get(u, ())):
            assert state.get(t) != 1, f"import circle: {' -> '.join([*path, u, t])}"
            if t not in state:
                visit(t, [*path, u])
        state[u] = 2

    for u in sorted(graph):
        if u not in state:
            visit(u, [])


def test_the_plant_knows_nothing_of_its_controllers() -> None:
    """The autopilot's side of the contract stands alone (an autopilot link replaces it)."""
    assert _imports()["plant"] <= {"config", "jit"}


def test_the_compile_cache_key_covers_what_kernels_can_read_and_no_driver() -> None:
    from uavmpc import jit

    root = Path(jit.__file__).resolve().parent
    names = {str(p.relative_to(root)) for p in jit._compiled_sources(root)}
    # Kernel modules, and what they import (constants and helpers frozen into machine code).
    assert {"jit.py", "tracker/kernels.py", "plant/kernels.py", "drivers/world.py",
            "onboard.py", "tracker/params.py"} <= names
    # Drivers and applications outside that closure change without a recompilation.
    assert not {"apps/cli.py", "drivers/node.py", "drivers/px4/sitl.py"} & names
