"""The sweep file of ``lidarctl sweep``: which configurations, targets and Monte-Carlo seeds to run.

A sweep is (configurations) x (targets) x (seeds). Configurations are the base configuration file
with dotted keys overridden: the full factorial of ``[grid]`` (a scalar is a fixed value, a list an
axis), times the explicit ``[[cases]]`` if any (each case a table of key = value). Keys are the
configuration's own (``laser``, ``lens``, ``profile``, ``link.tx_power_w``, ``scan.averages``,
``scan.max_range_m``, ``detector.balanced``, ``chirp.excursion_hz``, ...) so that a key added to
:mod:`lidard.config` (a chirp shape beyond the three-segment chirp and the triangle, a receiver variant such as
``adc.iq``) becomes sweepable by adding it to :data:`SWEEPABLE` once the task honours it; settings
that only the DSP has live under ``dsp.`` (``dsp.estimator``). Keys the task does not use are
refused with the reason, never silently ignored. Example (docs/scale-out.md has the full format)::

    [sweep]
    name = "lasers-powers"
    base_config = "sim.toml"          # next to this file, else config/<name> of the package
    seeds = 20                        # Monte-Carlo seeds 0..19 (or a list)
    trials_per_task = 8               # pixels per task (detection probability = hits / trials)

    [grid]
    laser = ["dfb_default", "dfb_broad_linewidth", "ideal"]
    "link.tx_power_w" = [3e-4, 1e-3, 3e-3]
    "scan.max_range_m" = 40.0

    [target]                          # a Lambertian plane facing the beam
    distances_m = { start = 2.0, stop = 40.0, num = 20 }
    reflectivity = 0.1
    velocity_mps = 0.0                # radial, positive receding

Every error is a :class:`SweepSpecError` naming the file and the dotted key (and the value).
"""

from __future__ import annotations

import hashlib
import itertools
import json
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from lidard.config import CONFIG_DIR, Config, LaserPreset, Profile, load_config
from lidard.dsp.ranging.estimators import DEFAULT_METHOD, EstimatorName
from lidard.errors import ConfigError, LidardError

Scalar = bool | int | float | str

# Configuration keys the sweep task honours (it builds the link budget, the ADC plan, the synthesis
# and the DSP from them exactly as the daemon and the bench do). Whole sections end with ".".
SWEEPABLE = ("profile", "lens", "laser", "chirp.", "detector.", "link.", "monitor.", "adc.bits",
             "adc.input_range_v", "adc.sfdr_dbc", "adc.max_sample_rate_hz", "adc.min_sample_rate_hz", "adc.oversample",
             "scan.averages", "scan.max_range_m", "scan.pfa", "scan.max_returns", "scan.window",
             "scan.max_speed_mps", "scan.phase_noise_compensation", "sim.effects.")
# Keys that exist but that the task cannot honour (yet), with the reason given to the user.
REFUSED = {
    "link.reflectivity": "the target's reflectivity is [target] reflectivity",
    "adc.iq": "the sweep task runs the real-beat DSP only (the I/Q receiver runs in scans and replays, not in sweeps yet)",
    "adc.bandwidth_hz": "it only enters the budget's eq. 2-19 term, which the synthesis replaces by real quantization",
    "monitor.quadrature": "the daemon's scan loop does not read a quadrature monitor yet",
}
DSP_KEYS = {"dsp.estimator"}


class SweepSpecError(LidardError):
    """The sweep file is invalid; the message names the file and the dotted key."""


class _Model(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Linspace(_Model):
    start: float = Field(gt=0, allow_inf_nan=False)
    stop: float = Field(gt=0, allow_inf_nan=False)
    num: int = Field(ge=1, le=10_000)
    log: bool = False

    def values(self) -> list[float]:
        f = np.geomspace if self.log else np.linspace
        return [float(x) for x in f(self.start, self.stop, self.num)]


class RunSection(_Model):
    name: str = Field(default="sweep", min_length=1)
    base_config: str = "sim.toml"
    seeds: Annotated[int, Field(ge=1)] | Annotated[list[int], Field(min_length=1)] = 10
    seed: int = 0                 # mixed into every task's random stream: a different Monte-Carlo draw
    trials_per_task: int = Field(default=8, ge=1, le=4096)

    def seed_list(self) -> list[int]:
        if isinstance(self.seeds, int):
            return list(range(self.seeds))
        return list(self.seeds)


PosFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
NonNegFloat = Annotated[float, Field(ge=0, allow_inf_nan=False)]
Speed = Annotated[float, Field(ge=-100, le=100, allow_inf_nan=False)]


class TargetSection(_Model):
    distances_m: Annotated[list[PosFloat], Field(min_length=1)] | Linspace
    reflectivity: NonNegFloat | Annotated[list[NonNegFloat], Field(min_length=1)] = 0.1
    velocity_mps: Speed | Annotated[list[Speed], Field(min_length=1)] = 0.0

    def axes(self) -> tuple[list[float], list[float], list[float]]:
        d = self.distances_m.values() if isinstance(self.distances_m, Linspace) else list(self.distances_m)
        rho = self.reflectivity if isinstance(self.reflectivity, list) else [self.reflectivity]
        vel = self.velocity_mps if isinstance(self.velocity_mps, list) else [self.velocity_mps]
        return [float(x) for x in d], [float(x) for x in rho], [float(x) for x in vel]


class SweepFile(_Model):
    sweep: RunSection = RunSection()
    grid: dict[str, Scalar | list[Scalar]] = {}
    cases: list[dict[str, Scalar]] = []
    target: TargetSection


class DspSettings(_Model):
    estimator: EstimatorName = DEFAULT_METHOD


@dataclass(frozen=True)
class SweepPoint:
    """One configuration of the sweep: the swept values and everything the task needs, resolved."""

    params: tuple[tuple[str, Scalar], ...]
    cfg: Config
    profile: Profile
    laser: LaserPreset
    dsp: DspSettings
    config_hash: str


@dataclass(frozen=True)
class SweepTask:
    """One task: a configuration, one target (distance, reflectivity, radial velocity) and one seed."""

    key: str
    point: SweepPoint
    distance_m: float
    reflectivity: float
    velocity_mps: float
    seed: int
    base_seed: int
    trials: int

    def describe(self) -> dict[str, Any]:
        """The task's parameters, as failures and rows report them."""
        return {**dict(self.point.params), "distance_m": self.distance_m, "reflectivity": self.reflectivity,
                "velocity_mps": self.velocity_mps, "seed": self.seed}


@dataclass(frozen=True)
class Sweep:
    name: str
    source: str
    points: list[SweepPoint]
    tasks: list[SweepTask]
    swept_keys: tuple[str, ...]


# ---------------------------------------------------------------------------------------------------
def _check_key(source: str, where: str, key: str) -> None:
    if key in REFUSED:
        raise SweepSpecError(f"{source}: {where}.{key}: cannot be swept: {REFUSED[key]}")
    if key in DSP_KEYS or key in SWEEPABLE:
        return
    if any(key.startswith(p) and len(key) > len(p) for p in SWEEPABLE if p.endswith(".")):
        return
    allowed = ", ".join(SWEEPABLE + tuple(sorted(DSP_KEYS)))
    raise SweepSpecError(f"{source}: {where}.{key}: not a key the sweep task honours; allowed: {allowed} "
                         "(a key ending in '.' stands for its whole section)")


def _set_dotted(data: dict, key: str, value: Scalar) -> None:
    *path, last = key.split(".")
    node = data
    for part in path:
        nxt = node.setdefault(part, {})
        if not isinstance(nxt, dict):
            raise KeyError(key)
        node = nxt
    node[last] = value


def _resolve_base(spec_path: Path, name: str) -> Path:
    p = Path(name).expanduser()
    for cand in ((p,) if p.is_absolute() else (spec_path.parent / p, CONFIG_DIR / p)):
        if cand.is_file():
            return cand
    raise SweepSpecError(f"{spec_path}: sweep.base_config: {name!r} not found next to the sweep file "
                         f"or in {CONFIG_DIR}")


def _point(source: str, base: Config, overrides: dict[str, Scalar], where: str) -> SweepPoint:
    data = base.model_dump(mode="python")
    dsp: dict[str, Scalar] = {}
    for key, value in overrides.items():
        if key.startswith("dsp."):
            dsp[key[4:]] = value
        else:
            _set_dotted(data, key, value)
    shown = ", ".join(f"{k}={v!r}" for k, v in overrides.items()) or "(base configuration)"
    try:
        cfg = Config.model_validate({**data, "source": f"{source} [{shown}]", "base_dir": base.base_dir})
        dsp_settings = DspSettings.model_validate(dsp)
    except ValidationError as exc:
        e = exc.errors()[0]
        loc = ".".join(str(x) for x in e["loc"])
        loc = f"dsp.{loc}" if dsp and loc in DspSettings.model_fields else loc
        msg = "unknown key" if e["type"] == "extra_forbidden" else e["msg"]
        raise SweepSpecError(f"{source}: {where}.{loc}: {msg} (got {e.get('input')!r}; in {shown})") from None
    try:
        profile, laser = cfg.resolved.profile, cfg.resolved.laser
    except ConfigError as exc:    # named by key: the point's source is said once, here
        raise SweepSpecError(f"{source}: {where}: {str(exc).removeprefix(cfg.source + ': ')} (in {shown})") from None
    # the configuration's content, not where its file lies: a sweep's tasks (and their seeds) are the
    # same in any checkout or data directory
    blob = json.dumps({"config": cfg.model_dump(mode="json", exclude={"path"}), "profile": profile.model_dump(mode="json"),
                       "laser": laser.model_dump(mode="json"), "dsp": dsp_settings.model_dump(mode="json")},
                      sort_keys=True)
    return SweepPoint(params=tuple(overrides.items()), cfg=cfg, profile=profile, laser=laser, dsp=dsp_settings,
                      config_hash=hashlib.sha256(blob.encode()).hexdigest()[:16])


def _combinations(spec: SweepFile) -> list[tuple[dict[str, Scalar], str]]:
    axes = [(k, v if isinstance(v, list) else [v]) for k, v in spec.grid.items()]
    for k, values in axes:
        if not values:
            raise SweepSpecError(f"grid.{k}: an empty list sweeps nothing")
    grid = [dict(zip([k for k, _ in axes], combo)) for combo in itertools.product(*[v for _, v in axes])]
    if not spec.cases:
        return [(g, "grid") for g in grid]
    return [({**g, **case}, f"cases[{i}]") for i, case in enumerate(spec.cases) for g in grid]


def task_key(point: SweepPoint, distance_m: float, reflectivity: float, velocity_mps: float, seed: int,
             base_seed: int, trials: int) -> str:
    """Stable identity of a task: what a restarted sweep compares to skip finished work."""
    blob = json.dumps([point.config_hash, repr(float(distance_m)), repr(float(reflectivity)),
                       repr(float(velocity_mps)), int(seed), int(base_seed), int(trials)])
    return hashlib.sha256(blob.encode()).hexdigest()[:20]


def load_sweep(path: str | Path) -> Sweep:
    """Read, validate and expand a sweep file into its configurations and tasks."""
    p = Path(path)
    try:
        raw = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise SweepSpecError(f"{p}: file not found") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise SweepSpecError(f"{p}: cannot read as TOML ({exc})") from None
    return expand_sweep(raw, source=str(p), base_dir=p.parent)


def expand_sweep(raw: dict, *, source: str = "<sweep>", base_dir: Path | None = None) -> Sweep:
    """Validate a sweep given as a dict (the parsed TOML) and expand it."""
    try:
        spec = SweepFile.model_validate(raw)
    except ValidationError as exc:
        e = exc.errors()[0]
        loc = ".".join(str(x) for x in e["loc"] if not str(x).startswith(("list[", "function-")))
        msg = "unknown key" if e["type"] == "extra_forbidden" else e["msg"]
        raise SweepSpecError(f"{source}: {loc}: {msg} (got {e.get('input')!r})") from None
    for where, table in [("grid", spec.grid)] + [(f"cases[{i}]", c) for i, c in enumerate(spec.cases)]:
        for key in table:
            _check_key(source, where, key)
    spec_path = (base_dir or Path.cwd()) / "sweep.toml"
    base = load_config(_resolve_base(spec_path, spec.sweep.base_config), environ={})
    points = [_point(source, base, ov, where) for ov, where in _combinations(spec)]
    seen: dict[str, int] = {}
    for i, pt in enumerate(points):
        if pt.config_hash in seen:
            raise SweepSpecError(f"{source}: configurations {seen[pt.config_hash]} and {i} are identical "
                                 f"({dict(pt.params)}): a key is listed twice?")
        seen[pt.config_hash] = i
    distances, refl, vels = spec.target.axes()
    run = spec.sweep
    tasks = [SweepTask(key=task_key(pt, d, r, v, s, run.seed, run.trials_per_task), point=pt, distance_m=d,
                       reflectivity=r, velocity_mps=v, seed=s, base_seed=run.seed, trials=run.trials_per_task)
             for pt in points for r in refl for v in vels for d in distances for s in run.seed_list()]
    if len({t.key for t in tasks}) != len(tasks):
        raise SweepSpecError(f"{source}: target/sweep.seeds: a distance, reflectivity, velocity or seed is "
                             "listed twice (the same task would run twice)")
    keys = tuple(dict.fromkeys(k for pt in points for k, _ in pt.params))
    return Sweep(name=run.name, source=source, points=points, tasks=tasks, swept_keys=keys)
