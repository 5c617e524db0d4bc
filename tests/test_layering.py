"""The layer rule of docs/design.md, section 2: a module imports only modules of its own layer
or the layers above it in the table (lower layers never import higher ones). Checked on the
source with :mod:`ast`, so lazy imports inside functions count too."""

from __future__ import annotations

import ast
from pathlib import Path

import jaxocean

PACKAGE = Path(jaxocean.__file__).parent

# docs/design.md's table, top (lowest) to bottom; names are relative to ``jaxocean``, and
# the longest matching prefix decides (``nn.cli`` is a CLI module inside the ``nn`` package)
LAYERS = (
    ("helpers", ("_math", "errors", "files", "_records", "_sea_scale", "compile_cache")),
    ("state", ("waves", "spectrum")),
    ("surface", ("_roughness", "hierarchy", "surface")),
    ("image", ("camera", "lens", "shading", "raycast", "render")),
    ("time", ("forecast",)),
    ("files", ("io", "radiometry", "rectify", "horizon", "_ground_grid", "spacetime", "plots")),
    ("inverse: fit", ("fit",)),
    ("inverse: nn", ("nn",)),
    ("applications", ("_stages", "footage", "reconstruct", "report", "demo", "cli", "_cli_inputs", "nn.cli",
                      "__main__")),
)
# (importer, imported): design.md names it -- fit.waves's init="net" start uses the wave network
KNOWN_EXCEPTIONS = {("fit.waves._select", "nn.waves")}


def _layer(name: str) -> int | None:
    """Index in :data:`LAYERS` of module ``name`` (relative to ``jaxocean``); None for the
    package itself, which re-exports the public names."""
    if name in ("", "__init__"):
        return None
    best = None
    for index, (_, modules) in enumerate(LAYERS):
        for prefix in modules:
            if (name == prefix or name.startswith(prefix + ".")) and (best is None or len(prefix) > len(best[1])):
                best = (index, prefix)
    assert best is not None, f"jaxocean.{name} is in no layer of docs/design.md's table"
    return best[0]


def _imports(path: Path) -> list[str]:
    """What ``path`` imports from ``jaxocean``, relative to it: ``from jaxocean.a import b`` gives
    ``a.b`` (``b`` a module or a name in ``a``; the layer lookup goes by prefix)."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom) and node.level == 0 and node.module and \
                (node.module == "jaxocean" or node.module.startswith("jaxocean.")):
            base = node.module.removeprefix("jaxocean").lstrip(".")
            found += [f"{base}.{a.name}".lstrip(".") for a in node.names]  # a name may be a submodule
        elif isinstance(node, ast.Import):
            found += [a.name.removeprefix("jaxocean").lstrip(".") for a in node.names
                      if a.name == "jaxocean" or a.name.startswith("jaxocean.")]
    return found


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def layer_violations() -> list[str]:
    out = []
    for path in sorted(PACKAGE.rglob("*.py")):
        name = _module_name(path)
        own = _layer(name)
        for target in _imports(path):
            other = _layer(target)
            if own is not None and other is not None and other > own and \
                    not any(name == a and (target == b or target.startswith(b + ".")) for a, b in KNOWN_EXCEPTIONS):
                out.append(f"jaxocean.{name} ({LAYERS[own][0]}) imports jaxocean.{target} ({LAYERS[other][0]})")
    return out


def test_no_module_imports_a_higher_layer():
    assert layer_violations() == []


def test_low_level_modules_do_not_import_nn():
    """radiometry and the fit package take the luminance weights from shading, not nn.geometry."""
    for path in [PACKAGE / "radiometry.py", *sorted((PACKAGE / "fit").rglob("*.py"))]:
        name = _module_name(path)
        bad = [t for t in _imports(path) if (t == "nn" or t.startswith("nn.")) and
               not any(name == a and (t == b or t.startswith(b + ".")) for a, b in KNOWN_EXCEPTIONS)]
        assert bad == [], f"jaxocean.{name} imports {bad}"


def test_luminance_is_reexported():
    from jaxocean import radiometry, shading
    from jaxocean.nn import geometry

    assert geometry.LUMINANCE is shading.LUMINANCE
    assert radiometry.LUMINANCE is shading.LUMINANCE
