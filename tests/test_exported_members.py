"""Each package that declares its public names (``__all__``) exports exactly names it has, each defined
inside the package (no re-export of a foreign object as the package's own), in a list with no
duplicates; and the package-level names are the very objects of the modules they come from."""

import importlib
import inspect

import pytest

PACKAGES = ["sim_devices.awg", "sim_devices.bench", "sim_devices.controller", "sim_devices.digitizer",
            "sim_devices.fpsa", "sim_devices.usb", "lidard.store", "lidard.outputs"]


@pytest.mark.parametrize("name", PACKAGES)
def test_every_exported_name_exists_and_is_the_packages_own(name):
    pkg = importlib.import_module(name)
    exported = pkg.__all__
    assert exported and len(set(exported)) == len(exported), f"{name}.__all__ repeats a name"
    missing = [n for n in exported if not hasattr(pkg, n)]
    assert not missing, f"{name}.__all__ names what it does not have: {missing}"
    for n in exported:
        obj = getattr(pkg, n)
        if inspect.isclass(obj) or inspect.isfunction(obj):
            # defined in a module of this package, and the package gives the module's own object
            assert obj.__module__.startswith(name + "."), (name, n, obj.__module__)
            assert getattr(importlib.import_module(obj.__module__), n) is obj


@pytest.mark.parametrize("name", PACKAGES)
def test_star_import_gives_exactly_the_exported_names(name):
    ns: dict = {}
    exec(f"from {name} import *", ns)
    assert sorted(k for k in ns if k != "__builtins__") == sorted(importlib.import_module(name).__all__)


def test_the_lidar_sim_entry_point_resolves():
    # pyproject's ``lidar-sim = "sim_devices.bench.bench:main"`` and the package's own ``main``
    from sim_devices import bench
    from sim_devices.bench import bench as module
    assert bench.main is module.main and callable(module.main)
