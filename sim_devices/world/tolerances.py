"""The bench's hidden truths: what a real instrument has and the daemon does not know.

A lab's LiDAR differs from its drawings. The daemon is configured with NOMINAL values (monitor MZI
delay ``[monitor] delay_s``, the FPSA optics of eq. 4-1 with a perfect lens) and must learn the
truth through its instruments (calibration). The simulated bench draws the true values ONCE, at
construction, from ``[sim.tolerances]`` (:class:`lidard.config.Tolerances`):

* monitor MZI delay: true = nominal x (1 + eps), eps ~ U(-mzi_delay_rel, +mzi_delay_rel). The
  daemon's chirp slope comes from the monitor's fringe rate (beat = kappa x tau_MZI, eq. 2-4 on the
  reference arm), so a relative delay error eps becomes a range SCALE error eps (0.5 % at 0.8 m:
  4 mm). The bound, 1 %: a fibre delay line cut to a length within ~4 cm of 40 m, and the fibre's
  group index known to ~0.5 %.
* range zero offset z0 ~ U(0, zero_offset_m): the optical path between the reference reflection
  (the fibre-array back-reflection that is the LO, §4.4.1) and the lens: the chip's waveguides, the
  switch tree, the free-space gap to the lens. A path LENGTH, so drawn in [0, bound], never
  negative. Every return's round trip is 2 (d + z0) / c while the geometric range d (lens ->
  surface) stays the truth: ranges come out z0 long until the range-zero calibration removes it.
  The bound, 5 cm: a few cm of silicon waveguide (group index ~4) plus the lens's back focal gap.
* pointing (:class:`lidard.physics.optics.Pointing`; directions of eq. 4-1 bent by it):
  focal_scale = 1 + U(-focal_rel, +focal_rel) (a stock lens's focal length is quoted to ~1 %);
  decentre U(-decentre_px, +decentre_px) pixel pitches per axis (die placement on the lens axis to
  ~1 pitch, 15-20 um); rotation U(-rotation_deg, +rotation_deg) about the optical axis (0.5 deg:
  what a die placed by hand under a microscope is within); radial distortion k1 U(-k1, +k1) in the
  one-term Brown model u (1 + k1 |u|^2) (a low-distortion F/1.4 25 mm lens: |k1| <~ 0.2, i.e.
  < 0.4 % barrel or pincushion at the FPSA's 8 deg edge field; the default bound 0.1 is half that).

* the coherent receiver (``adc.iq``): the 90-degree hybrid's quadrature error eps ~ U(-hybrid_phase_deg,
  +hybrid_phase_deg) and the Q/I gain ratio g = 10^(U(-hybrid_gain_db, +hybrid_gain_db) / 20) of its
  two photodiode chains (Q = g A sin(dPhi + eps), lidard.dsp.ranging.iqbalance). The bounds, 5 deg and 0.5 dB:
  what fibre 90-degree hybrids are specified to (+-5 deg) and two photodiodes' responsivities and TIA
  gains match to.

``draw = false`` takes each bound itself (+bound; z0 = bound) instead of a draw: sensitivity
studies. A bound of 0 switches that tolerance off; ``enabled = false`` switches all off (nominal:
the bench is exactly its configuration). Each tolerance has its own random stream (seeded by
``tolerances.seed``, else ``sim.seed``), so switching one off leaves the others' draws unchanged.

The laser's TEC tolerances (``tec_*``) belong to the laser model (sim_devices.world.laser); they
are not drawn here.

Who sees the truth: :class:`sim_devices.bench.Bench` keeps it (``Bench.truth()``, and the child
bench's control command ``{"cmd": "truth"}``) for tests and benchmarks only; the daemon never
reads it, nor ``[sim.tolerances]``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from lidard.physics.optics import Pointing

__all__ = ["BenchTruth", "draw_truth"]

# One random stream per tolerance: [seed, tag] (tags are arbitrary fixed constants).
_TAGS = {"mzi_delay": 0x13A1, "zero_offset": 0x13A2, "focal": 0x13A3, "decentre": 0x13A4,
         "rotation": 0x13A5, "k1": 0x13A6, "hybrid_gain": 0x13A7, "hybrid_phase": 0x13A8}


@dataclass(frozen=True)
class BenchTruth:
    """The true values of one bench (see the module docstring). SI units."""

    mzi_delay_s: float            # the monitor MZI's true delay
    zero_offset_m: float          # reference reflection -> lens optical path (one way), >= 0
    pointing: Pointing = field(default_factory=Pointing)
    #: the nominal MZI delay the daemon is configured with (for the relative error)
    nominal_mzi_delay_s: float | None = None
    iq_gain: float = 1.0          # the coherent receiver's Q / I gain ratio
    iq_phase_rad: float = 0.0     # and its quadrature phase error

    def __post_init__(self) -> None:
        if not (math.isfinite(self.mzi_delay_s) and self.mzi_delay_s > 0):
            raise ValueError(f"BenchTruth: mzi_delay_s must be positive, got {self.mzi_delay_s!r}")
        if not (math.isfinite(self.zero_offset_m) and self.zero_offset_m >= 0):
            raise ValueError(f"BenchTruth: zero_offset_m must be >= 0 (a path length), got {self.zero_offset_m!r}")

    @classmethod
    def nominal(cls, mzi_delay_s: float) -> BenchTruth:
        """A bench exactly as configured (tolerances off)."""
        return cls(float(mzi_delay_s), 0.0, Pointing(), float(mzi_delay_s))

    @property
    def mzi_delay_rel(self) -> float:
        """True delay / nominal - 1 (0 when the nominal is not known)."""
        if not self.nominal_mzi_delay_s:
            return 0.0
        return self.mzi_delay_s / self.nominal_mzi_delay_s - 1.0

    def as_dict(self) -> dict:
        """JSON-friendly (the control socket's ``truth`` reply); :meth:`from_dict` inverts it."""
        return {"mzi_delay_s": self.mzi_delay_s, "nominal_mzi_delay_s": self.nominal_mzi_delay_s,
                "mzi_delay_rel": self.mzi_delay_rel, "zero_offset_m": self.zero_offset_m,
                "pointing": self.pointing.as_dict(), "iq_gain": self.iq_gain, "iq_phase_rad": self.iq_phase_rad}

    @classmethod
    def from_dict(cls, d: dict) -> BenchTruth:
        p = d["pointing"]
        dx, dy = (float(x) for x in p["decentre_px"])
        return cls(float(d["mzi_delay_s"]), float(d["zero_offset_m"]),
                   Pointing(float(p["focal_scale"]), (dx, dy),
                            float(p["rotation_rad"]), float(p["k1"])),
                   d.get("nominal_mzi_delay_s"), float(d.get("iq_gain", 1.0)), float(d.get("iq_phase_rad", 0.0)))


def _symmetric(rng_seed: list[int], bound: float, draw: bool, size: int | None = None):
    """U(-bound, +bound) from its own stream, or +bound itself (draw = false); 0 when bound is 0."""
    if bound == 0.0:
        return 0.0 if size is None else np.zeros(size)
    if not draw:
        return bound if size is None else np.full(size, bound)
    return np.random.default_rng(rng_seed).uniform(-bound, bound, size)


def draw_truth(tolerances, *, nominal_mzi_delay_s: float, seed: int) -> BenchTruth:
    """The bench's true values from a ``lidard.config.Tolerances`` (``cfg.sim.tolerances``).

    ``seed``: ``sim.seed`` (or the bench's seed), used when ``tolerances.seed`` is None.
    """
    tol = tolerances
    if not tol.enabled:
        return BenchTruth.nominal(nominal_mzi_delay_s)
    s = int(seed if tol.seed is None else tol.seed)
    draw = bool(tol.draw)

    def stream(name: str) -> list[int]:
        return [s, _TAGS[name]]

    eps = float(_symmetric(stream("mzi_delay"), tol.mzi_delay_rel, draw))
    if tol.zero_offset_m == 0.0:
        z0 = 0.0
    elif draw:   # a path length: drawn in [0, bound], never negative
        z0 = float(np.random.default_rng(stream("zero_offset")).uniform(0.0, tol.zero_offset_m))
    else:
        z0 = float(tol.zero_offset_m)
    decentre = _symmetric(stream("decentre"), tol.decentre_px, draw, size=2)
    pointing = Pointing(
        focal_scale=1.0 + float(_symmetric(stream("focal"), tol.focal_rel, draw)),
        decentre_px=(float(decentre[0]), float(decentre[1])),
        rotation_rad=math.radians(float(_symmetric(stream("rotation"), tol.rotation_deg, draw))),
        k1=float(_symmetric(stream("k1"), tol.k1, draw)))
    gain_db = float(_symmetric(stream("hybrid_gain"), tol.hybrid_gain_db, draw))
    phase_deg = float(_symmetric(stream("hybrid_phase"), tol.hybrid_phase_deg, draw))
    return BenchTruth(mzi_delay_s=float(nominal_mzi_delay_s) * (1.0 + eps), zero_offset_m=z0,
                      pointing=pointing, nominal_mzi_delay_s=float(nominal_mzi_delay_s),
                      iq_gain=10.0 ** (gain_db / 20.0), iq_phase_rad=math.radians(phase_deg))
