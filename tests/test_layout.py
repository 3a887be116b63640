"""The package's import arrows point one way (docs/architecture.md): stages, then the per-UAV
program, then the drivers, then the applications; no circle between packages.

Every ``import`` in the package is read from the source, including the lazy ones inside
functions, which is where a circle would otherwise hide. So is every process the package
launches (``python -m uavmpc.x``, ``[sys.executable, "-m", "uavmpc.x"]``, ``[sys.executable,
"-c", CODE]``, a console script): a process of a higher tier started by a lower one is the
same arrow pointing up, one an import check cannot see.
"""

import ast
import itertools
import re
import tomllib
from pathlib import Path

import uavmpc

ROOT = Path(uavmpc.__file__).parent

#: Each unit of the package (a top-level module or package) and its tier; a unit may import
#: units of its own tier or below, never above.
TIERS: dict[str, int] = {
    "config": 0, "jit": 0, "data": 0, "typed_json": 0,
    "reference": 1, "solvers": 1, "plant": 1, "estimation": 1,
    "tracker": 2, "control": 2, "comms": 2, "missions": 2, "geofence": 2,
    "avoidance": 3,
    "onboard": 4, "supervisor": 4, "assumptions": 4,
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
    assert {"jit.py", "tracker/kernels.py", "plant/kernels.py", "drivers/world_tick.py",
            "onboard.py", "tracker/params.py"} <= names
    # Drivers and applications outside that closure change without a recompilation.
    assert not {"apps/cli.py", "apps/bench.py", "drivers/world.py", "drivers/node.py",
                "drivers/px4/sitl.py"} & names


# --- process launches ------------------------------------------------------------------------

#: ``-m uavmpc.x`` inside a command line written as one string.
_DASH_M = re.compile(r"(?<![\w-])-m\s+(uavmpc(?:\.\w+)*)")


def _console_scripts() -> dict[str, str]:
    """Console script name -> the module it runs (pyproject's [project.scripts]), when the
    package is run from its source tree."""
    pyproject = ROOT.parents[1] / "pyproject.toml"
    if not pyproject.exists():
        return {}
    scripts = tomllib.loads(pyproject.read_text()).get("project", {}).get("scripts", {})
    return {name: target.split(":")[0] for name, target in scripts.items()}


def _docstrings(tree: ast.AST) -> set[int]:
    """The ids of the docstring nodes of ``tree`` (documentation, not a launch)."""
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            body = node.body
            if (body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant)
                    and isinstance(body[0].value.value, str)):
                found.add(id(body[0].value))
    return found


def _imported(code: str) -> set[str]:
    """The modules a piece of Python code (``python -c CODE``) imports."""
    try:
        tree = ast.parse(code)
    except SyntaxError:
        return set()
    names: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def launches(source: str, scripts: dict[str, str] | None = None) -> set[str]:
    """The ``uavmpc`` modules a source text starts as processes: ``-m uavmpc.x`` in any string
    but a docstring; in an argument list (a list or tuple literal), ``"-m"`` then a module,
    ``"-c"`` then code (the modules it imports), or a console script first (``scripts``: name
    -> module). A module-level string constant stands for its value in an argument list."""
    scripts = _console_scripts() if scripts is None else scripts
    tree = ast.parse(source)
    constants: dict[str, str] = {}
    for node in tree.body if isinstance(tree, ast.Module) else []:
        target = value = None
        if isinstance(node, ast.Assign) and len(node.targets) == 1:
            target, value = node.targets[0], node.value
        elif isinstance(node, ast.AnnAssign):
            target, value = node.target, node.value
        if (isinstance(target, ast.Name) and isinstance(value, ast.Constant)
                and isinstance(value.value, str)):
            constants[target.id] = value.value

    def text(node: ast.AST) -> str | None:
        if isinstance(node, ast.Constant) and isinstance(node.value, str):
            return node.value
        if isinstance(node, ast.Name):
            return constants.get(node.id)
        return None

    docs = _docstrings(tree)
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Constant) and isinstance(node.value, str) and id(node) not in docs:
            found.update(_DASH_M.findall(node.value))
        elif isinstance(node, (ast.List, ast.Tuple)):
            args = [text(e) for e in node.elts]
            if args and args[0] in scripts:
                found.add(scripts[args[0]])
            for flag, value in itertools.pairwise(args):
                if flag == "-m" and value is not None:
                    found.add(value)
                elif flag == "-c" and value is not None:
                    found.update(_imported(value))
    return {m for m in found if m == "uavmpc" or m.startswith("uavmpc.")}


def upward_launches(sources: dict[str, list[str]],
                    scripts: dict[str, str] | None = None) -> list[tuple[str, str]]:
    """(unit, module) for every process a unit's sources launch from a higher tier (or from
    no known unit at all); ``sources``: unit -> its source texts."""
    found = []
    for unit, texts in sources.items():
        for text in texts:
            for module in sorted(launches(text, scripts)):
                target = _unit(module)
                if target not in TIERS or TIERS[target] > TIERS[unit]:
                    found.append((unit, module))
    return found


def _sources() -> dict[str, list[str]]:
    """unit -> the source texts of its files."""
    out: dict[str, list[str]] = {}
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT).with_suffix("")
        if rel.parts == ("__init__",):
            continue
        out.setdefault(rel.parts[0], []).append(path.read_text())
    return out


def test_process_launches_point_down_the_tiers() -> None:
    upward = upward_launches(_sources())
    assert upward == [], f"processes launched up the tiers: {upward}"


def test_the_package_launches_its_node_processes_from_the_driver_tier() -> None:
    """The swarm starts its nodes and stand-ins through the driver tier's entry point: the
    scan sees that launch (so it would see another)."""
    drivers = _sources()["drivers"]
    assert any("uavmpc.drivers.launch" in launches(text) for text in drivers)


SYNTHETIC = '''
"""Starts ``python -m uavmpc.apps.cli node``: a docstring, not a launch."""
import subprocess
import sys

CLI = "uavmpc.apps.cli"


def node() -> None:
    subprocess.Popen([sys.executable, "-m", "uavmpc.apps.cli", "node", "--id", "a"])


def sitl() -> None:
    subprocess.Popen([sys.executable, "-m", CLI, "sitl"])


def shell() -> None:
    subprocess.run(f"{sys.executable} -m uavmpc.apps.campaign run x", shell=True)


def code() -> None:
    subprocess.run((sys.executable, "-c", "from uavmpc.apps.bench import main; main()"))


def script() -> None:
    subprocess.run(["uavmpc", "swarm", "x"])


def below() -> None:
    subprocess.run([sys.executable, "-m", "uavmpc.drivers.launch", "spec.json"])
'''


def test_the_launch_check_catches_a_lower_tier_launching_a_higher_one() -> None:
    scripts = {"uavmpc": "uavmpc.apps.cli"}
    assert launches(SYNTHETIC, scripts) == {"uavmpc.apps.cli", "uavmpc.apps.campaign",
                                            "uavmpc.apps.bench", "uavmpc.drivers.launch"}
    # In a driver, every launch of an application is an arrow up; the driver's own is not.
    assert upward_launches({"drivers": [SYNTHETIC]}, scripts) == [
        ("drivers", "uavmpc.apps.bench"), ("drivers", "uavmpc.apps.campaign"),
        ("drivers", "uavmpc.apps.cli")]
    # The same text in an application launches nothing above it.
    assert upward_launches({"apps": [SYNTHETIC]}, scripts) == []
    # A stage launching a driver is caught too, and a module of no known unit.
    stage = 'import sys\nCMD = [sys.executable, "-m", "uavmpc.drivers.launch"]\n'
    assert upward_launches({"tracker": [stage]}, scripts) == [
        ("tracker", "uavmpc.drivers.launch")]
    assert upward_launches({"apps": ['ARGS = ["-m", "uavmpc.nowhere"]\n']}, scripts) == [
        ("apps", "uavmpc.nowhere")]
    # A docstring that only names a command line is not a launch.
    assert launches('"""Run ``python -m uavmpc.apps.cli node``."""\n', scripts) == set()
