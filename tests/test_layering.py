"""The house's floors (DESIGN.md, "The house as it should read"): every import, also one inside a
function or an ``if TYPE_CHECKING`` block, goes to the same floor or a lower one.

Floors, bottom to top: the robots vocabulary (``robots/{hal,transforms}.py``,
``robots/spot/{model,urdf,kinematics,motion}.py``) -> ``sim/`` -> the robot adapters
(``robots/spot/{sim_*,sdk_*,stall_watch,signals}.py``, ``robots/spot/fake_spot/``) ->
``helios/`` -> ``tasks/`` -> ``tools/``. ``sim`` using the robots vocabulary is downward here; the
one upward arrow by design is ``sim -> helios.perception`` (the protocols the simulated detector
implements). ``helios/schema.py``, the config machinery, imports nothing of ours and counts as the
bottom floor. An import that goes up anywhere else is a room on the wrong floor: move the room.
No two modules may import each other, directly or round a longer loop.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("helios", "robots", "sim", "tasks", "tools")
FLOOR_NAMES = ("robots vocabulary", "sim", "robot adapters", "helios", "tasks", "tools")
VOCABULARY = {"robots", "robots.hal", "robots.transforms", "robots.spot", "robots.spot.model", "robots.spot.urdf",
              "robots.spot.kinematics", "robots.spot.motion"}
CONFIG_MACHINERY = "helios.schema"
"""The config machinery (dataclasses as the schema, YAML, overrides, ``require``) serves the config
trees of every floor and imports nothing of ours, so it stands on the bottom floor (checked below)."""
ADAPTERS = ("robots.spot.sim_backend", "robots.spot.sim_arm", "robots.spot.sim_manipulation",
            "robots.spot.sdk_backend", "robots.spot.sdk_bringup",
            "robots.spot.sdk_commands", "robots.spot.sdk_config",
            "robots.spot.sdk_conversions", "robots.spot.sdk_futures", "robots.spot.sdk_shutdown",
            "robots.spot.stall_watch", "robots.spot.signals", "robots.spot.fake_spot")
UPWARD_BY_DESIGN = (("sim", "helios.perception"),)          # (importing floor, imported module or package)
NOT_IN_THE_METHOD = ("pybullet", "bosdyn", "sim", "tasks", "tools") + ADAPTERS


def _within(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def floor_of(module: str) -> int | None:
    if module == CONFIG_MACHINERY:
        return 0
    top = module.split(".")[0]
    if top == "robots":
        if module in VOCABULARY:
            return 0
        return 2 if any(_within(module, a) for a in ADAPTERS) else None
    return {"sim": 1, "helios": 3, "tasks": 4, "tools": 5}.get(top)


def modules(root: Path = ROOT) -> dict[str, Path]:
    """Dotted module name -> file, for every .py file of the packages (a package is its __init__)."""
    out = {}
    for package in PACKAGES:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            out[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return out


def imports(root: Path = ROOT) -> list[tuple[str, str, str]]:
    """(importing module, imported module, "file:line") for every import statement anywhere in
    the packages. An imported name that is a module of ours counts as that module; an import of
    ours that names no module counts as its nearest enclosing package that exists."""
    mods = modules(root)

    def ours(name: str) -> str:
        while name not in mods and "." in name:
            name = name.rpartition(".")[0]
        return name

    out = []
    for module, path in mods.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                targets = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):
                base = node.module or ""
                if node.level:
                    anchor = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                    base = ".".join(anchor + ([node.module] if node.module else []))
                targets = [f"{base}.{a.name}" if f"{base}.{a.name}" in mods else base for a in node.names]
            else:
                continue
            where = f"{path.relative_to(root)}:{node.lineno}"
            for target in targets:
                if target.split(".")[0] in PACKAGES:
                    target = ours(target)
                if target != module:
                    out.append((module, target, where))
    return list(dict.fromkeys(out))          # one entry per line, however many names it imports


def modules_without_a_floor(root: Path = ROOT) -> list[str]:
    return [f"{path.relative_to(root)}: {module} is on no floor (add it to this test's floors)"
            for module, path in modules(root).items() if floor_of(module) is None]


def upward_imports(root: Path = ROOT) -> list[str]:
    bad = []
    for source, target, where in imports(root):
        low, high = floor_of(source), floor_of(target)
        if low is None or high is None or high <= low:
            continue
        if any(_within(source, s) and _within(target, t) for s, t in UPWARD_BY_DESIGN):
            continue
        bad.append(f"{where}: {source} ({FLOOR_NAMES[low]}) imports {target} ({FLOOR_NAMES[high]}, a floor up)")
    return bad


def method_imports_of_the_testbed(root: Path = ROOT) -> list[str]:
    return [f"{where}: {source} imports {target}" for source, target, where in imports(root)
            if _within(source, "helios") and any(_within(target, n) for n in NOT_IN_THE_METHOD)]


def import_cycles(root: Path = ROOT) -> list[str]:
    """Strongly connected groups of modules (Tarjan), each with the imports that close it."""
    edges: dict[str, dict[str, str]] = {}
    for source, target, where in imports(root):
        if target.split(".")[0] in PACKAGES:
            edges.setdefault(source, {}).setdefault(target, where)
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    groups: list[list[str]] = []

    def visit(v: str) -> None:          # recursion depth <= number of modules (a few hundred)
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in edges.get(v, {}):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                groups.append(sorted(group))

    for v in sorted(modules(root)):
        if v not in index:
            visit(v)
    return [" <-> ".join(g) + " (" + "; ".join(f"{edges[a][b]} imports {b}" for a in g for b in edges.get(a, {})
                                               if b in g) + ")"
            for g in groups]


def test_every_module_is_on_a_floor():
    bad = modules_without_a_floor()
    assert not bad, "\n".join(bad)


def test_imports_go_down_the_floors():
    bad = upward_imports()
    assert not bad, "imports that go a floor up (move the room, do not hide the import):\n" + "\n".join(bad)


def test_the_method_never_imports_the_testbed():
    bad = method_imports_of_the_testbed()
    assert not bad, "helios/ must not import PyBullet, bosdyn, sim, tasks, tools or the robot adapters:\n" + \
        "\n".join(bad)


def test_no_import_cycles():
    bad = import_cycles()
    assert not bad, "modules that import each other:\n" + "\n".join(bad)


def test_the_checks_see_imports_inside_functions_and_type_checking_blocks(tmp_path):
    """The scanner itself, on a small made-up tree with one of each kind of offence."""
    files = {
        "helios/__init__.py": "",
        "helios/perception/__init__.py": "",
        "helios/agent.py": "def f():\n    import pybullet\n",
        "robots/__init__.py": "",
        "robots/hal.py": "",
        "robots/gripper.py": "",
        "sim/__init__.py": "from helios.perception import x\nfrom robots.hal import y\n",
        "sim/world.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from tasks import runner\n",
        "tasks/__init__.py": "",
        "tasks/a.py": "def f():\n    from . import b\n",
        "tasks/b.py": "from tasks.a import f\n",
        "tools/__init__.py": "",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    assert modules_without_a_floor(tmp_path) == ["robots/gripper.py: robots.gripper is on no floor "
                                                 "(add it to this test's floors)"]
    assert upward_imports(tmp_path) == ["sim/world.py:3: sim.world (sim) imports tasks (tasks, a floor up)"]
    assert method_imports_of_the_testbed(tmp_path) == ["helios/agent.py:2: helios.agent imports pybullet"]
    assert import_cycles(tmp_path) == ["tasks.a <-> tasks.b (tasks/a.py:2 imports tasks.b; tasks/b.py:1 imports "
                                       "tasks.a)"]


def test_rooms_stay_small():
    """The agent's decision file stays under 450 lines and no class of the method over 400: a
    skill that grows goes to a room of its own (README, "Layout")."""
    agent = ROOT / "helios" / "agents" / "helios_agent.py"
    assert len(agent.read_text().splitlines()) < 450, f"{agent.relative_to(ROOT)}: split it further"
    big = []
    for path in sorted((ROOT / "helios").rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.ClassDef) and node.end_lineno - node.lineno + 1 > 400:
                big.append(f"{path.relative_to(ROOT)}:{node.lineno} class {node.name} "
                           f"({node.end_lineno - node.lineno + 1} lines)")
    assert not big, "classes over 400 lines: " + "; ".join(big)
