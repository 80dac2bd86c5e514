"""The package's layout rules, read from the sources with Python's own parser (``ast``): no import circle among
jaxmocap's modules (imports inside functions count), the core never imports a wing (``synth``, ``parsec``), no
module over 800 lines, jaxopt imported by ``fit/solvers.py`` only, and the public API of ``jaxmocap/__init__.py``
resolves without importing JAX up front."""

import ast
import pathlib
import subprocess
import sys

import jaxmocap

PKG = pathlib.Path(jaxmocap.__file__).resolve().parent
WINGS = ("jaxmocap.synth", "jaxmocap.parsec")
#: the application layer: it may reach every package, wings included
APP = ("jaxmocap.cli", "jaxmocap.demo")


def _module_name(path: pathlib.Path) -> str:
    parts = path.relative_to(PKG.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {_module_name(p): p for p in sorted(PKG.rglob("*.py"))}


def _imports(path: pathlib.Path) -> set[str]:
    """Every jaxmocap module that ``path`` imports, at any depth of its code (``from a import b`` counts as
    ``a.b`` when that is a module, else as ``a``)."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {a.name for a in node.names if a.name.startswith("jaxmocap")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("jaxmocap"):
            for a in node.names:
                sub = f"{node.module}.{a.name}"
                out.add(sub if sub in MODULES else node.module)
    return {m for m in out if m in MODULES}


GRAPH = {m: _imports(p) for m, p in MODULES.items()}


def _is_package_init(name: str) -> bool:
    return MODULES[name].name == "__init__.py"


def test_no_import_circle():
    # a package's __init__ that re-exports its own modules is part of that package, not a step of a circle:
    # the edges kept are module -> module
    graph = {
        m: {d for d in deps if not _is_package_init(d)}
        for m, deps in GRAPH.items()
        if not _is_package_init(m)
    }
    state: dict[str, int] = {}
    circles = []

    def visit(m, stack):
        state[m] = 1
        stack.append(m)
        for d in sorted(graph.get(m, ())):
            if state.get(d) == 1:
                circles.append(stack[stack.index(d) :] + [d])
            elif d not in state:
                visit(d, stack)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m, [])
    assert not circles, "\n".join(" -> ".join(c) for c in circles)


def test_core_never_imports_a_wing():
    wing = lambda m: any(m == w or m.startswith(w + ".") for w in WINGS)
    offending = {
        m: sorted(d for d in deps if wing(d)) for m, deps in GRAPH.items() if not wing(m) and m not in APP
    }
    assert not {m: d for m, d in offending.items() if d}


def test_modules_are_at_most_800_lines():
    long = {m: n for m, p in MODULES.items() if (n := len(p.read_text().splitlines())) > 800}
    assert not long


def test_jaxopt_only_behind_the_solvers_module():
    users = set()
    for m, p in MODULES.items():
        for node in ast.walk(ast.parse(p.read_text())):
            names = (
                [a.name for a in node.names]
                if isinstance(node, ast.Import)
                else [node.module or ""]
                if isinstance(node, ast.ImportFrom)
                else []
            )
            if any(n.split(".")[0] == "jaxopt" for n in names):
                users.add(m)
    assert users == {"jaxmocap.fit.solvers"}


def test_public_api_resolves_lazily():
    code = (
        "import sys, jaxmocap\n"
        "assert 'jax' not in sys.modules, 'import jaxmocap imported jax'\n"
        "missing = [n for n in jaxmocap.__all__ if getattr(jaxmocap, n, None) is None]\n"
        "assert not missing, missing\n"
        "from jaxmocap.likelihood.compose import Likelihood\n"
        "assert jaxmocap.Likelihood is Likelihood\n"
        "print('ok')\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip() == "ok", proc.stderr[-2000:]
