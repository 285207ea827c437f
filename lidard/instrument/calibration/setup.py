"""What a range, pointing or I/Q calibration record was measured on, and whether a scan may use it.

A calibration is a property of one set-up, not of a data directory: the effective monitor delay and the
zero offset (:mod:`.range`) belong to the laser and its chirp, the monitor interferometer and the
receiver chain; the pointing model (:mod:`.pointing`) to the FPSA chip behind its lens. A record made on
one set-up and applied to another would still say ``calibrated: true`` while its ranges or directions
carry the other set-up's errors. So every record names its set-up, and a scan uses only the newest
record of each kind whose set-up is its own (:func:`select`); otherwise that kind is uncalibrated with
the reason (which part differs).

A set-up is a few named parts, each a short hash of what it consists of:

* range / I/Q: the laser preset's values, the ``[chirp]``, ``[monitor]``, ``[adc]``, ``[detector]`` and
  ``[link]`` sections (the scan's max speed only sets the ADC rate of a scan: it is in ``[scan]``, left out);
* pointing: the scanner profile and lens (their optics summary);
* both: the instruments. On real hardware these are the identities the devices report (model, serial,
  firmware); on a simulated bench the bench is the instrument: its seed and ``[sim.tolerances]`` (the
  drawn truths are not read, only what draws them).

Light (stdlib only) so that the job queue and the API load it without the DSP.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

KINDS = ("range", "pointing", "iq")
_RANGE_SECTIONS = ("chirp", "monitor", "adc", "detector", "link")
#: keys of those sections that set how the DSP judges points, not what the receiver measures: a range
#: or I/Q calibration made under one value holds under another (the harmonic screen's level)
_JUDGEMENT_ONLY = {"adc": ("sfdr_dbc",)}


def _digest(value: Any) -> str:
    return hashlib.sha256(json.dumps(value, sort_keys=True, default=str).encode()).hexdigest()[:12]


@dataclass(frozen=True)
class Setup:
    """One kind's set-up: named parts (``{"laser": "dfb_default", "optics": "<hash>", ...}``) and their hash."""

    parts: dict[str, str] = field(default_factory=dict)

    @property
    def hash(self) -> str:
        return _digest(self.parts)

    def as_dict(self) -> dict[str, Any]:
        return {"hash": self.hash, "parts": dict(self.parts)}

    def differs(self, other: dict[str, Any] | None) -> str | None:
        """Why a record's set-up ``other`` (its ``as_dict``) is not this one, or None when it is."""
        if not other or "hash" not in other:
            return "it names no set-up (made before calibrations were tied to their set-up)"
        if other["hash"] == self.hash:
            return None
        theirs = other.get("parts") or {}
        diff = [f"{k} {theirs.get(k)!s} here {v!s}" if k in ("laser", "profile", "lens") else k
                for k, v in self.parts.items() if theirs.get(k) != v]
        return "it was made on another set-up (" + (", ".join(diff) or "set-up hash") + " differ)"


@dataclass(frozen=True)
class CalibrationSetup:
    """The set-up of each calibration kind of one instrument under one configuration."""

    kinds: dict[str, Setup]

    def __getitem__(self, kind: str) -> Setup:
        return self.kinds[kind]

    @property
    def hash(self) -> str:
        """One key for all kinds (the user cache of factory calibrations, lidard.store.calcache)."""
        return _digest({k: s.hash for k, s in sorted(self.kinds.items())})


def calibration_setup(cfg, identities: dict[str, Any] | None = None) -> CalibrationSetup:
    """The set-up of ``cfg`` with the devices' reported ``identities`` (real hardware; ignored on a
    simulated bench, whose devices all report the same simulator identities)."""
    data = cfg.model_dump(mode="json")
    if cfg.sim.enabled:
        bench = {"seed": data["sim"]["seed"], "tolerances": data["sim"]["tolerances"]}
    else:
        bench = {k: str(v) for k, v in sorted((identities or {}).items())}
    profile = cfg.resolved.profile
    lens = cfg.lens or profile.default_lens
    receiver = {"laser_preset": cfg.resolved.laser.model_dump(mode="json"), "chirp": data["chirp"],
                **{s: {k: v for k, v in data[s].items() if k not in _JUDGEMENT_ONLY.get(s, ())}
                   for s in _RANGE_SECTIONS if s != "chirp"}}
    instruments = _digest(bench)
    rng = Setup({"laser": cfg.laser, "receiver": _digest(receiver), "instruments": instruments})
    pointing = Setup({"profile": profile.name, "lens": str(lens),
                      "optics": _digest(cfg.resolved.optics.summary()), "instruments": instruments})
    return CalibrationSetup({"range": rng, "iq": rng, "pointing": pointing})


def instrument_setup(cfg, instrument) -> CalibrationSetup:
    """:func:`calibration_setup` of ``cfg`` with the identities ``instrument``'s devices reported when
    it was opened (its device registry; none for an instrument without one)."""
    registry = getattr(instrument, "registry", None)
    return calibration_setup(cfg, dict(getattr(registry, "identity", None) or {}))


def mode_differs(inputs: dict[str, Any] | None, phase_noise: str | None) -> str | None:
    """Why a range record (its ``inputs``) does not fit a scan whose phase-noise compensation is
    ``phase_noise`` ("on"/"off"; None: any), or None when it does.

    The compensation subtracts the monitor's measured phase, which holds the linearized chirp's
    deterministic residual as well as the laser's phase noise, so the same target reads a slightly
    different range with it on and off (docs/measured/26_range_linearity.md): a scale and offset fitted
    in one mode are the set-up's in that mode only. A record that does not say its mode (made before
    records named it) fits any scan."""
    made = (inputs or {}).get("phase_noise_compensation")
    if phase_noise is None or made is None or made == phase_noise:
        return None
    return (f"its plates were measured with phase-noise compensation {made}, this scan has it {phase_noise} "
            "(scan.phase_noise_compensation; measure plates in this scan's mode)")


def select(records, setup: Setup | None, phase_noise: str | None = None) -> tuple[Any, str | None]:
    """The newest of ``records`` (newest first; ``.id``, ``.inputs["setup"]``) made on ``setup``, and
    why none was when there are records but none fits (None: no records, or a match). ``phase_noise``:
    the scan's resolved phase-noise compensation ("on"/"off"), which a range record must have been
    measured in as well (:func:`mode_differs`); None: any.

    Without a ``setup`` (an instrument whose set-up is not known, e.g. a test double) the newest record
    is used, as before calibrations named their set-up."""
    records = list(records)
    if not records:
        return None, None

    def why(rec) -> str | None:
        inputs = rec.inputs or {}
        return ((None if setup is None else setup.differs(inputs.get("setup")))
                or (mode_differs(inputs, phase_noise) if rec.kind == "range" else None))
    for rec in records:
        if why(rec) is None:
            return rec, None
    newest = records[0]
    return None, f"{newest.kind} calibration {newest.id} not used: {why(newest)}"
