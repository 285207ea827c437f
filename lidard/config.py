"""Typed configuration: pydantic models loaded from TOML, with environment overrides.

A configuration file (``config/sim.toml``, ``config/lab.toml``) names a scanner *profile*
(``config/profiles/<name>.toml``: the FPSA of dissertation §4.2 or §4.3 with its lenses, switch
dynamics and Table 4-4 losses), a *laser preset* (``config/profiles/lasers.toml``) and holds the chirp
(§4.4.1), detector/TIA/ADC and link-budget parameters (Table 2-2, §4.4.2), the device addresses and the
simulation settings.

Rooms: the section models live in :mod:`lidard.config_models.sections`, the profile and
laser preset models in :mod:`lidard.config_models.presets`; this module composes them into
:class:`Config`, loads files and applies environment overrides (in :func:`load_config` only), resolves
the presets a configuration names once into an immutable :class:`ResolvedConfig` (``cfg.resolved``),
and re-exports every model.

Environment overrides: ``LIDARD__SECTION__KEY=value`` sets ``[section] key`` (value parsed as a TOML
literal when it parses, else taken as a string), e.g. ``LIDARD__ADC__BITS=12``.

Errors: every problem becomes one :class:`ConfigError` whose message names the file, the dotted key
and what is allowed. Loading is all-or-nothing: a :class:`Config` object exists only if everything
validated.
"""

from __future__ import annotations

import functools
import os
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pydantic import Field, PrivateAttr, ValidationError, field_validator, model_validator

from .config_models.base import Fraction, NonNegFloat, PosFloat, _Model  # noqa: F401  (re-exported)
from .config_models.presets import (  # noqa: F401  (re-exported: lidard.config is the public path)
    BondedRows, FpsaLosses, LaserPreset, Lens, Profile, SwitchTiming, ThermalTerm,
)
from .config_models.sections import (  # noqa: F401  (re-exported)
    Adc, AwgDevice, Chirp, ControllerDevice, Daemon, Detector, Devices, Effects, FpsaDevice, Link, Live, Tolerances,
    Monitor, ScanDefaults, Sim, UsbDevice,
)
from .errors import ConfigError, describe_validation
from .physics.budget import LinkParams, optical_bandwidth_hz
from .physics.optics import FpsaOptics

CONFIG_DIR = Path(__file__).resolve().parent.parent / "config"
ENV_PREFIX = "LIDARD__"


# --------------------------------------------------------------------------------------------------
# The main configuration (its sections: lidard.config_models.sections; presets: .presets)
# --------------------------------------------------------------------------------------------------
class Config(_Model):
    profile: str = "fpsa128"
    lens: str | None = None
    laser: str = "dfb_default"
    chirp: Chirp = Chirp()
    detector: Detector = Detector()
    adc: Adc = Adc()
    link: Link = Link()
    monitor: Monitor = Monitor()
    scan: ScanDefaults = ScanDefaults()
    devices: Devices = Devices()
    sim: Sim = Sim()
    daemon: Daemon = Daemon()
    live: Live = Live()

    # Resolved by load_config (not part of the file format).
    source: str = Field(default="<defaults>", exclude=True)
    # The file read (None: built-in defaults); a simulated bench started as a child process reads it
    # too. Kept by model_dump so a config re-validated with an override still names its file.
    path: str | None = None
    base_dir: str = Field(default=str(CONFIG_DIR), exclude=True)
    # the presets this configuration names, resolved on first use (see resolved)
    _resolved: tuple[tuple[Any, ...], ResolvedConfig] | None = PrivateAttr(default=None)

    @field_validator("profile", "laser")
    @classmethod
    def _name(cls, v: str) -> str:
        if not v or "/" in v or "\\" in v:
            raise ValueError("must be a plain preset name (a file under config/profiles)")
        return v

    @model_validator(mode="after")
    def _iq_on_the_triangle(self) -> Config:
        if self.adc.iq and self.chirp.shape != "triangle":
            raise ValueError("adc.iq = true: a coherent (I/Q) receiver measures the beat's sign on the triangle "
                             "alone; set chirp.shape = \"triangle\" (the three-segment chirp is for one photodiode)")
        return self

    # -- resolved views -------------------------------------------------------------------------
    def resolve_path(self, path: str) -> Path:
        p = Path(path).expanduser()
        return p if p.is_absolute() else Path(self.base_dir) / p

    @property
    def resolved(self) -> ResolvedConfig:
        """The profile, laser preset and optics this configuration names (:func:`resolve`), read and
        checked once per configuration: every later use is the same immutable object, with no file
        access. A copy with other presets (``model_copy(update=...)``) resolves its own."""
        key = (self.base_dir, self.profile, self.lens, self.laser, self.chirp.wavelength_m,
               self.devices.controller.laser_current_ma)
        cached = self._resolved
        if cached is None or cached[0] != key:
            cached = (key, resolve(self))
            self._resolved = cached
        return cached[1]

    # views of ``resolved`` under their older names (no file is read again)
    def load_profile(self) -> Profile:
        return self.resolved.profile

    def load_laser(self) -> LaserPreset:
        return self.resolved.laser

    def optics(self) -> FpsaOptics:
        return self.resolved.optics

    def link_params(self, profile: Profile | None = None, laser: LaserPreset | None = None) -> LinkParams:
        return link_params(self, profile or self.resolved.profile, laser or self.resolved.laser)


@dataclass(frozen=True)
class ResolvedConfig:
    """What a configuration's names stand for: its scanner ``profile`` (config/profiles/<name>.toml),
    its ``laser`` preset (config/profiles/lasers.toml) and the FPSA ``optics`` of its lens at its
    wavelength. Built by :func:`resolve`; a configuration hands out one (:attr:`Config.resolved`)."""

    profile: Profile
    laser: LaserPreset
    optics: FpsaOptics


def resolve(cfg: Config) -> ResolvedConfig:
    """Read (once per file version, shared by every configuration) and validate the presets ``cfg``
    names, and check the file's keys that depend on them: the laser current against the preset's
    maximum, the lens against the profile's lenses. A ConfigError names the file and the key."""
    profiles_dir = Path(cfg.base_dir) / "profiles"
    path = _profile_path(cfg.profile, profiles_dir)
    profile = _profile_file(path, _stamp(path))
    laser = load_laser(cfg.laser, profiles_dir)
    current = cfg.devices.controller.laser_current_ma
    if current > laser.max_current_ma:
        raise ConfigError(f"{cfg.source}: devices.controller.laser_current_ma: {current:g} mA is above the maximum "
                          f"current {laser.max_current_ma:g} mA of laser preset {cfg.laser!r} (max_current_ma)")
    if cfg.lens is not None and cfg.lens not in profile.lenses:
        raise ConfigError(f"{cfg.source}: lens: {cfg.lens!r} is not a lens of profile {profile.name}; "
                          f"allowed: {', '.join(sorted(profile.lenses))}")
    return ResolvedConfig(profile=profile, laser=laser,
                          optics=_optics(path, _stamp(path), cfg.lens, cfg.chirp.wavelength_m))


def link_params(cfg: Config, profile: Profile, laser: LaserPreset) -> LinkParams:
    """Turn the configured set-up into the numbers eqs. 2-9..2-21 need."""
    lens = profile.lenses[cfg.lens or profile.default_lens]
    ln = cfg.link
    aperture = ln.rx_aperture_m or lens.aperture_m
    common: dict[str, Any] = dict(
        wavelength_m=cfg.chirp.wavelength_m, ramp_s=cfg.chirp.ramp_s,
        coherence_time_s=laser.coherence_time_s, rin_db_per_hz=laser.rin_db_per_hz,
        responsivity_a_per_w=cfg.detector.responsivity_a_per_w,
        tia_gain_v_per_a=cfg.detector.tia_gain_v_per_a, cmrr_db=cfg.detector.effective_cmrr_db,
        temperature_k=cfg.detector.temperature_k, adc_range_v=cfg.adc.input_range_v,
        adc_bits=cfg.adc.bits, adc_bandwidth_hz=cfg.adc.bandwidth_hz,
        ambient_psd_w_per_hz=ln.ambient_psd_w_per_hz,
        optical_bandwidth_hz=optical_bandwidth_hz(ln.optical_bandwidth_m, cfg.chirp.wavelength_m),
        rx_aperture_m=aperture, reflectivity=ln.reflectivity,
    )
    if ln.reference == "backreflection":
        losses = profile.losses if ln.fpsa_losses == "measured" or profile.losses_improved is None \
            else profile.losses_improved
        return LinkParams(
            source_power_w=ln.fiber_power_w,
            ref_fraction=10 ** (ln.backreflection_db / 10),
            tx_fraction=ln.tx_power_w / ln.fiber_power_w,
            eta_rx=10 ** (-losses.total_db / 10),
            **common,
        )
    return LinkParams(
        source_power_w=ln.laser_power_w, ref_fraction=ln.r_ref,
        tx_fraction=ln.eta_tx * (1 - ln.r_ref), eta_rx=ln.eta_rx, **common,
    )


# --------------------------------------------------------------------------------------------------
# Loading
# --------------------------------------------------------------------------------------------------
def _format_validation(source: str, err: ValidationError) -> str:
    return describe_validation(err.errors(), source=source, show_input=True)


def _read_toml(path: Path) -> dict:
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(f"{path}: file not found") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{path}: cannot read ({exc})") from None
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{path}: not valid TOML ({exc})") from None


def _parse_env_value(raw: str) -> Any:
    try:
        return tomllib.loads(f"v = {raw}")["v"]
    except tomllib.TOMLDecodeError:
        return raw


def apply_env_overrides(data: dict, environ: dict[str, str] | None = None) -> tuple[dict, list[str]]:
    """Return a copy of ``data`` with ``LIDARD__A__B=value`` variables applied, and their names."""
    env = os.environ if environ is None else environ
    out = _deep_copy(data)
    applied = []
    for name, raw in sorted(env.items()):
        if not name.startswith(ENV_PREFIX) or len(name) <= len(ENV_PREFIX):
            continue
        path = [p.lower() for p in name[len(ENV_PREFIX):].split("__")]
        node = out
        for key in path[:-1]:
            nxt = node.setdefault(key, {})
            if not isinstance(nxt, dict):
                raise ConfigError(f"environment {name}: {key} is not a section")
            node = nxt
        node[path[-1]] = _parse_env_value(raw)
        applied.append(name)
    return out, applied


def _deep_copy(d: Any) -> Any:
    if isinstance(d, dict):
        return {k: _deep_copy(v) for k, v in d.items()}
    if isinstance(d, list):
        return [_deep_copy(v) for v in d]
    return d


def load_config(path: str | os.PathLike | None = None, *, environ: dict[str, str] | None = None,
                check_presets: bool = True) -> Config:
    """Load and validate a configuration file (default: built-in defaults + env overrides).

    Relative paths inside the file (scenes) resolve against the ``config/`` directory the file lives
    in, or the packaged ``config/`` for the defaults. The named profile and laser preset are loaded too
    (``check_presets``), so a typo there fails here, not in the middle of a scan.
    """
    if path is None:
        data, source, base = {}, "<defaults>", CONFIG_DIR
    else:
        p = Path(path)
        data, source = _read_toml(p), str(p)
        base = p.resolve().parent
        if not (base / "profiles").is_dir():
            base = CONFIG_DIR
    data, applied = apply_env_overrides(data, environ)
    if applied:
        source = f"{source} (+env {', '.join(applied)})"
    try:
        cfg = Config.model_validate({**data, "source": source, "base_dir": str(base),
                                     "path": None if path is None else str(path)})
    except ValidationError as exc:
        raise ConfigError(_format_validation(source, exc)) from None
    if check_presets:
        _ = cfg.resolved      # resolved now: a typo in a preset name fails here
    return cfg


def available_profiles(profiles_dir: Path = CONFIG_DIR / "profiles") -> list[str]:
    return sorted(p.stem for p in profiles_dir.glob("*.toml") if p.stem != "lasers")


# The preset files are read once: every configuration that names one (resolve, from the API, the CLI,
# the instrument and the bench alike) shares the one parsed, validated (frozen) model of a file; a
# configuration resolved after the file changed (its mtime and size) reads the new version.
def _stamp(path: Path) -> tuple[int, int]:
    st = path.stat()
    return st.st_mtime_ns, st.st_size


def load_profile(name: str, profiles_dir: Path = CONFIG_DIR / "profiles") -> Profile:
    path = _profile_path(name, profiles_dir)
    return _profile_file(path, _stamp(path))


def _profile_path(name: str, profiles_dir: Path) -> Path:
    path = Path(profiles_dir) / f"{name}.toml"
    if name == "lasers" or not path.is_file():
        raise ConfigError(f"profile: {name!r} not found in {profiles_dir}; allowed: "
                          f"{', '.join(available_profiles(Path(profiles_dir)))}")
    return path.resolve()


@functools.lru_cache(maxsize=32)
def _profile_file(path: Path, stamp: tuple[int, int]) -> Profile:
    data = _read_toml(path)
    try:
        return Profile.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(_format_validation(str(path), exc)) from None


@functools.lru_cache(maxsize=32)
def _optics(path: Path, stamp: tuple[int, int], lens: str | None, wavelength_m: float) -> FpsaOptics:
    return _profile_file(path, stamp).optics(lens, wavelength_m)


def load_lasers(profiles_dir: Path = CONFIG_DIR / "profiles") -> dict[str, LaserPreset]:
    path = Path(profiles_dir) / "lasers.toml"
    try:
        stamp = _stamp(path)
    except OSError:
        stamp = (0, 0)            # not there: _read_toml names it
    return dict(_lasers_file(path.resolve(), stamp))


@functools.lru_cache(maxsize=32)
def _lasers_file(path: Path, stamp: tuple[int, int]) -> dict[str, LaserPreset]:
    data = _read_toml(path)
    presets = data.get("laser")
    if not isinstance(presets, dict) or not presets:
        raise ConfigError(f"{path}: laser: expected tables [laser.<name>]")
    out = {}
    for name, body in presets.items():
        try:
            out[name] = LaserPreset.model_validate(body)
        except ValidationError as exc:
            raise ConfigError(_format_validation(f"{path}", exc).replace(f"{path}: ", f"{path}: laser.{name}.")) from None
    return out


def load_laser(name: str, profiles_dir: Path = CONFIG_DIR / "profiles") -> LaserPreset:
    presets = load_lasers(profiles_dir)
    if name not in presets:
        raise ConfigError(f"laser: {name!r} is not a preset; allowed: {', '.join(sorted(presets))}")
    return presets[name]
