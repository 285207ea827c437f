"""No dead option can come back (issue 11 item 2): every field of the configuration model -- walked
recursively through its nested models, the scanner profile and the laser preset included -- must be
read somewhere in lidard/, drivers/ or sim_devices/ outside lidard/config.py.

A "read" is found in the syntax tree, not by grep: an attribute access ``x.name``, a subscript or
``.get`` with the string ``"name"``, or the exact string ``"name"`` (getattr, dict keys of a
model_dump). Keyword arguments (``f(name=...)``) are writes and do not count. Inside config.py only
attribute reads in code that derives a value other modules use (properties, link_params) count,
listed in CONSUMED_IN_CONFIG with the reason.
"""

from __future__ import annotations

import ast
import typing
from pathlib import Path

from pydantic import BaseModel

from lidard import config as config_mod
from lidard.config import Config, LaserPreset, Profile

REPO = Path(__file__).resolve().parents[2]
SOURCES = ("lidard", "drivers", "sim_devices")

# Fields read only by config.py's own derived values, which the rest of the code uses. Each entry:
# (model, field): the derived value that carries it out of config.py.
CONSUMED_IN_CONFIG = {
    ("Lens", "f_number"): "Lens.aperture_m (link_params: the receive aperture)",
    ("BondedRows", "skip_every"): "Profile.bonded_rows",
    ("BondedRows", "skip_offset"): "Profile.bonded_rows",
    ("FpsaLosses", "fiber_coupling_db"): "FpsaLosses.total_db (link_params)",
    ("FpsaLosses", "waveguide_db"): "FpsaLosses.total_db (link_params)",
    ("FpsaLosses", "row_switch_db"): "FpsaLosses.total_db (link_params)",
    ("FpsaLosses", "col_switch_db"): "FpsaLosses.total_db (link_params)",
    ("FpsaLosses", "antenna_db"): "FpsaLosses.total_db (link_params)",
    ("FpsaLosses", "lens_db"): "FpsaLosses.total_db (link_params)",
    ("Profile", "losses"): "link_params (the one-way FPSA losses, Table 4-4)",
    ("Profile", "losses_improved"): "link_params (link.fpsa_losses = 'improved')",
    ("Link", "fiber_power_w"): "link_params",
    ("Link", "backreflection_db"): "link_params",
    ("Link", "tx_power_w"): "link_params",
    ("Link", "fpsa_losses"): "link_params",
    ("Link", "laser_power_w"): "link_params",
    ("Link", "r_ref"): "link_params",
    ("Link", "eta_tx"): "link_params",
    ("Link", "eta_rx"): "link_params",
    ("Link", "rx_aperture_m"): "link_params",
    ("Link", "ambient_psd_w_per_hz"): "link_params",
    ("Link", "optical_bandwidth_m"): "link_params",
    ("Link", "reflectivity"): "link_params",
    ("Detector", "cmrr_db"): "Detector.effective_cmrr_db (link_params)",
    ("Detector", "balanced"): "Detector.effective_cmrr_db (link_params)",
    ("Chirp", "excursion_hz"): "Chirp.rate_hz_per_s",
    ("Chirp", "velocity_resolution_mps"): "Chirp.cw_s (the constant segment's length: trigger period, records)",
    ("ThermalTerm", "gain_hz_per_v"): "LaserPreset.static_tuning_hz_per_v",
    ("Adc", "bits"): "Adc.record_bits (the digitizer's configured resolution) and link_params",
    ("Adc", "max_sample_rate_hz"): "Adc.record_bits",
}

# Fields whose wiring is still pending (none: keep it empty; an entry needs the reason next to it).
PENDING_WIRING: set[tuple[str, str]] = set()


# lidard.config and the models it re-exports (lidard/config_models/) are one module, split for size
_CONFIG_FILES = {Path(config_mod.__file__).resolve(),
                 *(p.resolve() for p in (REPO / "lidard" / "config_models").glob("*.py"))}


def _models(tp) -> list[type[BaseModel]]:
    """The pydantic models inside an annotation (X, X | None, list[X], dict[str, X])."""
    if isinstance(tp, type) and issubclass(tp, BaseModel):
        return [tp]
    out = []
    for arg in typing.get_args(tp):
        out += _models(arg)
    return out


def _fields(root: type[BaseModel], seen: set) -> list[tuple[str, str]]:
    if root in seen:
        return []
    seen.add(root)
    out = []
    for name, info in root.model_fields.items():
        out.append((root.__name__, name))
        for sub in _models(info.annotation):
            out += _fields(sub, seen)
    return out


def _reads(tree: ast.AST) -> set[str]:
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load):
            names.add(node.attr)
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and node.value.isidentifier():
            names.add(node.value)
    return names


def _used_outside_config() -> set[str]:
    names: set[str] = set()
    for top in SOURCES:
        for path in (REPO / top).rglob("*.py"):
            if path.resolve() in _CONFIG_FILES:
                continue
            names |= _reads(ast.parse(path.read_text(encoding="utf-8"), str(path)))
    return names


def _used_in_config_code() -> set[str]:
    """Attribute reads in config.py (not strings: its messages name every key)."""
    tree = ast.Module(body=[node for p in _CONFIG_FILES
                            for node in ast.parse(p.read_text(encoding="utf-8")).body], type_ignores=[])
    return {n.attr for n in ast.walk(tree) if isinstance(n, ast.Attribute) and isinstance(n.ctx, ast.Load)}


def test_every_config_field_is_read_somewhere():
    fields = []
    seen: set = set()
    for root in (Config, Profile, LaserPreset):
        fields += _fields(root, seen)
    assert ("Adc", "bandwidth_hz") in fields and ("ThermalTerm", "tau_s") in fields  # the walk recursed
    outside = _used_outside_config()
    in_config = _used_in_config_code()
    dead = [f"{m}.{n}" for m, n in fields
            if n not in outside and (m, n) not in PENDING_WIRING
            and not ((m, n) in CONSUMED_IN_CONFIG and n in in_config)]
    assert not dead, ("configuration fields read nowhere (make them act or remove them): " + ", ".join(dead))


def test_the_allow_list_names_only_real_fields_read_in_config_py():
    fields = set()
    for root in (Config, Profile, LaserPreset):
        fields |= set(_fields(root, set()))
    in_config = _used_in_config_code()
    stale = [f"{m}.{n}" for (m, n) in CONSUMED_IN_CONFIG if (m, n) not in fields or n not in in_config]
    assert not stale, stale
