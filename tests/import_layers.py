"""Read every module's imports (ast) and check them against the project's layers.

The layers, bottom to top (docs/explanations/architecture.md):
- ``goniofrost.core``: errors, config checks, atomic files, cache, grid. Imports nothing of the project.
- the lower packages ``planner``, ``drivers``, ``calib``, ``sim``: of goniofrost, only the core;
  among themselves only as ``LOWER_ALLOWED`` says (the twins in sim share the drivers' protocol
  modules, calib decodes frames with the drivers' RAW reader).
- ``goniofrost.rig`` (rig file, devices real or simulated, lock, stop path): of goniofrost, only the
  core; the lower packages as it likes. It sits below every other sub-package (``capture`` uses it).
- ``goniofrost.plan`` (making a plan, PLAN.json): of goniofrost, only ``PLAN_MAY`` (core, rig, frost);
  it sits below ``capture``, which reads PLAN.json through it.
- goniofrost's sub-packages (``frost``, ``brdf``, ``datasets``, ``capture``, ``bench``...): anything
  below them, and each other without a cycle; but ``capture`` imports neither ``sim`` nor
  ``goniofrost.datasets`` (``CAPTURE_NEVER``): its caller hands it the devices and the material.
- no cycle between modules either, inside a package as between packages (``module_graph``).
- ``goniofrost.app`` (command line, commands, demo): may import everything; nothing imports it
  but ``goniofrost/__main__.py``.
Imports inside functions count the same as those at the top of a module.
"""
from __future__ import annotations

import ast
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

PROJECT = "goniofrost"
CORE = "goniofrost.core"
APP = "goniofrost.app"
RIG = "goniofrost.rig"
CAPTURE = "goniofrost.capture"
PLAN = "goniofrost.plan"
PLAN_MAY = (CORE, RIG, "goniofrost.frost")
CAPTURE_NEVER = ("sim", "goniofrost.datasets")
LOWER = ("planner", "drivers", "calib", "sim")
LOWER_ALLOWED = {"planner": set(), "drivers": set(), "calib": {"drivers"}, "sim": {"drivers", "calib", "planner"}}
TOP_LEVEL_MODULES = {"__init__", "__main__"}


@dataclass(frozen=True)
class Violation:
    """One import that breaks a layer rule: where, what, and the rule."""

    module: str
    imported: str
    rule: str

    def __str__(self) -> str:
        return f"{self.module} imports {self.imported}: {self.rule}"


def module_name(root: Path, path: Path) -> str:
    """Dotted module name of ``path`` (a .py file under ``root``)."""
    parts = list(path.relative_to(root).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def import_statements(root: Path, path: Path) -> tuple:
    """Each import of the module at ``path`` (functions' too) as (target, names, from_module):
    ``import a.b`` is ("a.b", None, True); ``from T import x, y`` is (T, ("x", "y"), True) with
    relative imports resolved; ``from . import x`` is (the package, ("x",), False)."""
    name = module_name(root, path)
    package = name.split(".") if path.name == "__init__.py" else name.split(".")[:-1]
    return _import_statements(tuple(package), path.read_text(), str(path))


@lru_cache(maxsize=None)
def _import_statements(package: tuple, text: str, filename: str) -> tuple:
    """import_statements of a module's text, parsed once per process: a check reads every module
    three times (the package graph twice, the module graph once)."""
    found = []
    for node in ast.walk(ast.parse(text, filename=filename)):
        if isinstance(node, ast.Import):
            found += [(alias.name, None, True) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = list(package[: len(package) - node.level + 1]) if node.level else []
            found.append((".".join(base + ([node.module] if node.module else [])), tuple(a.name for a in node.names),
                          bool(node.module)))
    return tuple(found)


def imports_of(root: Path, path: Path) -> set[str]:
    """Absolute dotted names that the module at ``path`` imports (relative imports resolved)."""
    found = set()
    for target, names, from_module in import_statements(root, path):
        if names is None or from_module:
            found.add(target)
        else:  # from . import x: each x may be a module
            found.update(f"{target}.{n}" for n in names)
    return found


def unit_of(module: str) -> str | None:
    """The layer unit a module belongs to: a lower package, ``goniofrost.<sub>``, or None (outside)."""
    parts = module.split(".")
    if parts[0] in LOWER:
        return parts[0]
    if parts[0] == PROJECT:
        return ".".join(parts[:2]) if len(parts) > 1 else PROJECT
    return None


def package_graph(root: Path) -> dict[str, dict[str, set[str]]]:
    """unit -> {imported unit -> the modules of the unit that import it}."""
    graph: dict[str, dict[str, set[str]]] = {}
    for package in (PROJECT, *LOWER):
        for path in sorted((root / package).rglob("*.py")):
            module = module_name(root, path)
            here = unit_of(module)
            for imported in imports_of(root, path):
                there = unit_of(imported)
                if there is not None and there != here:
                    graph.setdefault(here, {}).setdefault(there, set()).add(module)
    return graph


def violations(root: Path) -> list[Violation]:
    """Every import of the tree under ``root`` that breaks a layer rule, sorted."""
    found = []
    for here, targets in package_graph(root).items():
        for there, modules in targets.items():
            rule = _rule_broken(here, there)
            found += [Violation(m, there, rule) for m in modules if rule]
    found += _cycles(root)
    found += _module_cycles(root)
    found += _top_level_modules(root)
    return sorted(set(found), key=str)


def _rule_broken(here: str, there: str) -> str | None:
    """The rule that ``here`` importing ``there`` breaks, or None."""
    if here == CORE:
        return "the bottom layer imports nothing of the project"
    if here in LOWER:
        if there.startswith(PROJECT) and there != CORE:
            return f"{here} may import only {CORE} of goniofrost"
        if there in LOWER and there not in LOWER_ALLOWED[here]:
            return f"{here} may import only {sorted(LOWER_ALLOWED[here]) or 'no other lower package'}"
        return None
    if here == RIG and there.startswith(PROJECT) and there != CORE:
        return f"{RIG} may import only {CORE} of goniofrost"
    if here == PLAN and there.startswith(PROJECT) and there not in PLAN_MAY:
        return f"{PLAN} may import only {', '.join(PLAN_MAY)} of goniofrost"
    if here == CAPTURE and there in CAPTURE_NEVER:
        return f"{CAPTURE} imports neither {' nor '.join(CAPTURE_NEVER)}: its caller hands it the devices and the material"
    if there == APP and here not in (PROJECT, f"{PROJECT}.__main__"):
        return f"nothing imports the application layer {APP}"
    if there == PROJECT:
        return "import the sub-package that holds it, not the goniofrost package itself"
    return None


def _cycles(root: Path) -> list[Violation]:
    """One violation per module whose import closes a cycle between two packages."""
    full = package_graph(root)
    graph = {here: set(targets) for here, targets in full.items()}
    return [Violation(module, there, f"cycle: {there} imports {here} back (directly or through others)")
            for here, targets in full.items() for there, modules in targets.items()
            if _reaches(graph, there, here) for module in modules]


def project_modules(root: Path) -> dict[str, Path]:
    """Dotted name -> file of every module of the project (goniofrost and the lower packages)."""
    return {module_name(root, path): path for package in (PROJECT, *LOWER)
            for path in sorted((root / package).rglob("*.py"))}


def module_graph(root: Path) -> dict[str, set[str]]:
    """module -> the project modules it imports. ``from P import x`` is an import of module P.x
    when there is one, else of P; a name inside a module is an import of that module."""
    modules = project_modules(root)
    graph = {}
    for name, path in modules.items():
        owners = {_owning_module(imported, modules) for imported in module_imports(root, path, modules)}
        graph[name] = owners - {None, name}
    return graph


def module_imports(root: Path, path: Path, modules) -> set[str]:
    """Absolute dotted names the module at ``path`` imports, ``from P import x`` as ``P.x`` when
    that is one of ``modules`` and as ``P`` otherwise (relative imports resolved)."""
    found = set()
    for target, names, _from_module in import_statements(root, path):
        if names is None:
            found.add(target)
        else:
            found.update(f"{target}.{n}" if f"{target}.{n}" in modules else target for n in names)
    return found


def _owning_module(imported: str, modules) -> str | None:
    """The longest dotted prefix of ``imported`` that is a project module, or None."""
    parts = imported.split(".")
    for end in range(len(parts), 0, -1):
        if ".".join(parts[:end]) in modules:
            return ".".join(parts[:end])
    return None


def _module_cycles(root: Path) -> list[Violation]:
    """One violation per import of a module that closes a cycle between modules."""
    graph = module_graph(root)
    return [Violation(here, there, f"module cycle: {there} imports {here} back (directly or through others)")
            for here, targets in graph.items() for there in sorted(targets) if _reaches(graph, there, here)]


def _reaches(graph: dict[str, set[str]], start: str, goal: str) -> bool:
    """True when ``goal`` is reachable from ``start`` along the import graph."""
    seen, todo = set(), [start]
    while todo:
        node = todo.pop()
        if node == goal:
            return True
        if node not in seen:
            seen.add(node)
            todo.extend(graph.get(node, ()))
    return False


def _top_level_modules(root: Path) -> list[Violation]:
    """goniofrost/ keeps only __init__ and __main__ at its top level: code lives in a sub-package."""
    return [Violation(f"{PROJECT}.{p.stem}", "-", "goniofrost/ holds sub-packages; move this module into one")
            for p in sorted((root / PROJECT).glob("*.py")) if p.stem not in TOP_LEVEL_MODULES]
