"""The package's layers (docs/architecture.md): imports point one way only, from the top
(cli) down to geometry, and the library packages hold no command-line job."""

import re
from pathlib import Path

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "hyperbones"
# Lower numbers sit lower: a module may import its own package and any lower layer.
LAYER = {"errors": 0, "io_utils": 0, "devices": 0, "geometry": 1, "physics": 2, "body": 3, "motion": 3,
         "garment": 3, "export": 3, "viz": 3, "rig": 4, "models": 4, "runtime": 5, "training": 5, "jobs": 6,
         "viewer": 7, "cli": 8}
# Within a layer, these may import one another in the direction given and no other.
SIDEWAYS = {("training", "runtime"), ("garment", "body"), ("motion", "body"), ("viz", "body"), ("viz", "motion"),
            ("devices", "errors"), ("io_utils", "errors")}


def _imports():
    for path in PACKAGE.rglob("*.py"):
        package = path.relative_to(PACKAGE).parts[0].removesuffix(".py")
        for match in re.finditer(r"^\s*(?:from|import) hyperbones\.(\w+)", path.read_text(), re.M):
            if match.group(1) != package:
                yield path.relative_to(PACKAGE), package, match.group(1)


def test_every_package_has_a_layer():
    packages = {path.name.removesuffix(".py") for path in PACKAGE.iterdir()
                if path.suffix == ".py" and path.name != "__init__.py" or (path / "__init__.py").exists()}
    assert packages == set(LAYER)


def test_imports_point_down_the_layers():
    upward = [f"{path}: {package} imports {target}" for path, package, target in _imports()
              if LAYER[target] > LAYER[package]
              or (LAYER[target] == LAYER[package] and (package, target) not in SIDEWAYS)]
    assert not upward, upward


def test_sideways_imports_go_one_way():
    pairs = {(package, target) for _, package, target in _imports() if LAYER[target] == LAYER[package]}
    assert not {(a, b) for a, b in pairs if (b, a) in pairs}
