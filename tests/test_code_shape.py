"""The code's shape stays readable (docs/architecture.md, "Reading the code"): no function of
plain Python over 80 lines (a compiled kernel is one numerical law, written as one function),
the world and the per-UAV program small, and ``Any`` only where a value is truly dynamic.

Each rule reads the source, so that a change that breaks it fails here, naming the place.
"""

import ast
import functools
from pathlib import Path

import uavmpc

ROOT = Path(uavmpc.__file__).parent
#: The longest function of plain Python [lines, decorators and docstring included].
MAX_FUNCTION_LINES = 80
#: ``Any`` in annotations other than as the value type of a JSON-shaped mapping.
MAX_BARE_ANY = 120


@functools.cache
def _trees() -> dict[str, ast.Module]:
    return {str(p.relative_to(ROOT)): ast.parse(p.read_text(), str(p))
            for p in sorted(ROOT.rglob("*.py"))}


def _is_kernel(fn: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    """Decorated with ``@kernel`` or ``@kernel(...)`` (:func:`uavmpc.jit.kernel`)."""
    for d in fn.decorator_list:
        target = d.func if isinstance(d, ast.Call) else d
        if isinstance(target, ast.Name) and target.id == "kernel":
            return True
    return False


def _bare_any(annotation: ast.expr) -> int:
    """How many ``Any`` an annotation holds, not counting ``dict[str, Any]``-style values."""
    if isinstance(annotation, ast.Constant) and isinstance(annotation.value, str):
        annotation = ast.parse(annotation.value, mode="eval").body
    if isinstance(annotation, ast.Subscript):
        base = ast.unparse(annotation.value).rsplit(".", 1)[-1]
        sl = annotation.slice
        if base in ("dict", "Mapping", "MutableMapping") and isinstance(sl, ast.Tuple) \
                and len(sl.elts) == 2:
            value = sl.elts[1]
            return _bare_any(sl.elts[0]) + (
                0 if isinstance(value, ast.Name) and value.id == "Any" else _bare_any(value))
    if isinstance(annotation, ast.Name):
        return int(annotation.id == "Any")
    if isinstance(annotation, ast.Attribute):
        return int(annotation.attr == "Any")
    return sum(_bare_any(c) for c in ast.iter_child_nodes(annotation)
               if isinstance(c, ast.expr))


def _annotations(tree: ast.Module) -> list[ast.expr]:
    out: list[ast.expr] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            a = node.args
            args = [*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg]
            out += [x.annotation for x in args if x is not None and x.annotation is not None]
            if node.returns is not None:
                out.append(node.returns)
        elif isinstance(node, ast.AnnAssign):
            out.append(node.annotation)
    return out


def test_the_counter_of_bare_any_counts_what_it_should() -> None:
    def count(source: str) -> int:
        return sum(map(_bare_any, _annotations(ast.parse(source))))

    assert count("def f(a: Any, b: dict[str, Any]) -> list[Any]: ...") == 2
    assert count("x: 'Mapping[str, Any]'\ny: 'tuple[Any, ...]'") == 1
    assert count("def f(a: typing.Any) -> dict[Any, int]: ...") == 2


def test_no_plain_function_is_over_80_lines() -> None:
    long = [f"{path}:{fn.lineno} {fn.name} ({fn.end_lineno - fn.lineno + 1} lines)"
            for path, tree in _trees().items() for fn in ast.walk(tree)
            if isinstance(fn, ast.FunctionDef | ast.AsyncFunctionDef) and not _is_kernel(fn)
            and fn.end_lineno is not None
            and fn.end_lineno - fn.lineno + 1 > MAX_FUNCTION_LINES]
    assert long == [], "split into named pieces: " + "; ".join(long)


def test_any_only_where_a_value_is_truly_dynamic() -> None:
    per_file = {path: n for path, tree in _trees().items()
                if (n := sum(map(_bare_any, _annotations(tree))))}
    assert sum(per_file.values()) < MAX_BARE_ANY, sorted(per_file.items(), key=lambda x: -x[1])


def _class(path: str, name: str) -> ast.ClassDef:
    tree = _trees()[path]
    return next(n for n in tree.body if isinstance(n, ast.ClassDef) and n.name == name)


def test_the_world_stays_a_driver_of_at_most_400_lines() -> None:
    world = _class("drivers/world.py", "World")
    assert world.end_lineno is not None
    assert world.end_lineno - world.lineno + 1 <= 400


def test_the_onboard_stack_keeps_a_small_public_interface() -> None:
    """At most 16 public methods and properties: the round's calls live in its ``steering``
    (:class:`uavmpc.avoidance.round.Steering`)."""
    stack = _class("onboard.py", "OnboardStack")
    public = {n.name for n in stack.body
              if isinstance(n, ast.FunctionDef) and not n.name.startswith("_")}
    assert len(public) <= 16, sorted(public)
