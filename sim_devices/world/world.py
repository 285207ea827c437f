"""The simulated world shared by every device on the bench: scanner optics, scene, laser, link budget.

Turns "pixel (row, col) lit with switch-path transmission T" into beat tones: ray casting (only the
rays of the pixels actually captured, cached per pixel), the Lambertian return of eq. 2-10 with the
FPSA's Table 4-4 losses on the way back, the beat amplitude G_TIA R sqrt(P_ref P_rx) of eq. 2-11, and
the white noise floor of eqs. 2-16..2-18 and 2-20/2-21. The phase-noise pedestal (eq. 2-15) and the ADC
term (eq. 2-19) are not added as white noise: the synthesis makes them happen (Wiener phase noise,
quantization).

Round trip through the switches: the FPSA is used as transmitter and receiver (§4.4.1), so a beam's
switch-path transmission T (from the MEMS dynamics) multiplies the returned power twice (out and back).
The back-reflection LO arises at the fibre array, before the switches, so P_ref does not depend on T.

Hidden truths (:mod:`sim_devices.world.tolerances`): given a ``BenchTruth``, the beams
leave along the TRUE pointing (``optics.with_pointing(truth.pointing)``: focal scale, decentre,
rotation, k1 bend eq. 4-1), and every hit's round trip is 2 (d + z0) / c, z0 the optical path from
the reference reflection (the LO) to the lens, while ``range_m`` and :meth:`World.ground_truth` stay
the geometric lens -> surface distance d along the true beam (what the scans are scored against).
The link budget uses d too: z0 is inside the instrument, it neither spreads nor attenuates the beam.

Targets move during a scan: a beam fired at scene time t (its trigger, counted from the
run's first trigger) sees every moving target translated by v t; velocities also give the Doppler
shifts and the within-segment range drift of the synthesis. Static targets are cast once per pixel
and cached; moving ones are cast per beam at its time (sim_devices.world.motion). ``rays_cast``
counts the cached casts, ``moving_rays_cast`` the per-beam ones.

Mixed pixels: on every scene that does not switch them off (``mixed_pixels = false``),
pixels whose beam footprint can reach a static target's outline are re-cast with footprint sub-rays
(``sub_rays_cast`` counts them; sim_devices.world.footprint) and, where the samples see other targets
than the central ray, give the footprint's weighted returns instead (sim_devices.world.mixed_returns).
The central ray's hits stay cached: :meth:`World.ground_truth` is still the single-ray truth, and
scores a mixed pixel's point against its footprint's nearest surface when given ``measured_m``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lidard.config import Config, LaserPreset, Profile
from lidard.physics.budget import LinkParams, asd_components
from lidard.physics.constants import C_M_PER_S
from lidard.physics.optics import FpsaOptics

from . import footprint as fp
from . import mixed_returns as mr
from . import motion
from .hit_store import HitStore
from .scene import Scene
from .speckle import speckle_factors
from .tolerances import BenchTruth

WHITE_NOISES = ("shot", "rin", "thermal", "ambient")


@dataclass(frozen=True)
class BeamHits:
    """Hits of a batch of beams, flattened: one entry per (beam, hit)."""

    beam: np.ndarray           # int index into the beam batch
    range_m: np.ndarray
    tau_s: np.ndarray          # round-trip delay 2 (d + z0) / c, z0 the hidden zero offset
    amplitude_v: np.ndarray    # beat amplitude at the ADC input (V), eq. 2-11 x G_TIA
    velocity_mps: np.ndarray   # radial, positive receding
    return_index: np.ndarray   # order along the beam (0 = nearest)
    #: beat phase of hits on speckle targets (NaN elsewhere); None when no hit is on one
    speckle_phase_rad: np.ndarray | None = None
    #: beams of the batch whose footprint crossed an outline (weighted returns; fidelity ledger)
    mixed_beams: int = 0


class World:
    """Scene + optics + link budget, with a per-pixel ray-cast cache."""

    def __init__(self, cfg: Config, profile: Profile, laser: LaserPreset, scene: Scene,
                 *, max_hits: int = 4, seed: int = 0, truth: BenchTruth | None = None) -> None:
        self.cfg = cfg
        self.profile = profile
        self.laser = laser
        # None: the nominal bench (exactly what the configuration says, no hidden tolerance)
        self.truth = truth
        optics = profile.optics(cfg.lens, cfg.chirp.wavelength_m)
        self.optics: FpsaOptics = optics if truth is None else optics.with_pointing(truth.pointing)
        self.zero_offset_m = 0.0 if truth is None else float(truth.zero_offset_m)
        self.link: LinkParams = cfg.link_params(profile, laser)
        self.max_hits = max_hits
        self.seed = int(seed)  # speckle draws
        self.rays_cast = 0          # pixels cast into the static targets (then cached)
        self.moving_rays_cast = 0   # beams cast into the moving targets, each at its own time
        self.sub_rays_cast = 0      # footprint sub-rays (mixed pixels: only around target outlines)
        self.set_scene(scene)

    def set_scene(self, scene: Scene) -> None:
        self.scene = scene
        self._white_asd: tuple[LinkParams, float] | None = None    # (link, white-noise ASD)
        self._hits_store = HitStore()        # the hits of every pixel cast (central ray; footprint if mixed)
        self._mixed: dict[int, tuple] = {}   # footprint-weighted returns of the mixed pixels
        self._speckle = np.array([bool(t.speckle) for t in scene.targets], bool)
        self._moving = np.array([bool(np.any(t.velocity != 0)) for t in scene.targets], bool)
        self._motion = motion.SceneMotion.of(scene)

    # -- noise ------------------------------------------------------------------------------------
    def white_noise_asd_v(self) -> float:
        """ASD of the white noises at the ADC input (shot, RIN, thermal, ambient), V/sqrt(Hz); kept
        for the link it was computed for (LinkParams is frozen: a new link is a new object), every
        read of the bench asks for it."""
        if self._white_asd is None or self._white_asd[0] is not self.link:
            c = asd_components(self.link, 1.0)  # white terms do not depend on distance (P_ref >> P_rx)
            self._white_asd = (self.link, float(np.sqrt(sum(float(c[k]) ** 2 for k in WHITE_NOISES))))
        return self._white_asd[1]

    # -- beams ------------------------------------------------------------------------------------
    def _cast_pixels(self, rows: np.ndarray, cols: np.ndarray) -> None:
        """Cast the pixels at (rows, cols) not cast yet, each once, and store their hits
        (:class:`~sim_devices.world.hit_store.HitStore`; the mixed ones' footprints too)."""
        rows, cols = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
        miss = self._hits_store.missing(rows, cols)
        if not miss.any():
            return
        missing = np.unique(rows[miss] * 4096 + cols[miss])
        d = self.optics.directions(missing // 4096, missing % 4096)
        h = self._static_cast(d)
        self.rays_cast += len(missing)
        self._hits_store.add_cast(missing // 4096, missing % 4096, h)
        if self.scene.mixed_pixels:
            self._sample_footprints(missing, d, h)

    def precast(self, rows, cols) -> None:
        """Cast and cache the pixels at (rows, cols) not cast yet, in one vectorized call. A scan's
        reads hold a few tens of pixels each; casting its next pixels in one go costs a fifth of
        casting them read by read (the per-call work is Python, held under the GIL on the bench's
        read path). The cache is per pixel, so the answers are the same either way."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        if rows.size:
            self._cast_pixels(rows, cols)

    def is_mixed(self, rows, cols) -> np.ndarray:
        """(n,) True where the bench gives the pixel footprint-weighted returns (cast on demand)."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        self._cast_pixels(rows, cols)
        return self._hits_store.mixed(rows, cols)

    def _static_cast(self, d: np.ndarray, origin=(0.0, 0.0, 0.0)):
        """Cast into the static targets, hits naming their index in the whole scene."""
        m = self._motion
        h = m.static.cast(d, max_hits=self.max_hits, origin=origin)
        if m.static is self.scene or m.static_index.size == 0:
            return h            # (nothing static: every slot is empty, -1)
        idx = np.where(h.target_index >= 0, m.static_index[np.maximum(h.target_index, 0)], -1)
        return replace(h, target_index=idx)

    def _beam(self) -> dict:
        lens = self.profile.lenses[self.cfg.lens or self.profile.default_lens]
        return {"emission_w_m": self.optics.emission_w_m, "focal_m": self.optics.focal_m,
                "wavelength_m": self.optics.wavelength_m, "aperture_m": lens.aperture_m}

    def _footprint_radius(self, range_m):
        return fp.footprint_radius_m(range_m, **self._beam())

    def range_bin_m(self) -> float:
        """One range bin c / 2B: closer returns blend into one tone."""
        return C_M_PER_S / (2.0 * abs(self.cfg.chirp.excursion_hz))

    def _sample_footprints(self, keys: np.ndarray, d: np.ndarray, h) -> None:
        """Mixed pixels: re-cast the footprints that may cross a target outline (sim_devices.world.footprint)."""
        cand = np.flatnonzero(fp.edge_candidates(self._motion.static.targets, d, self._footprint_radius))
        if cand.size == 0:
            return
        b = self._beam()
        o, sd = fp.sub_rays(d[cand], fp.beam_waist_m(**b),
                            fp.divergence_half_angle_rad(emission_w_m=b["emission_w_m"], focal_m=b["focal_m"]))
        sub = self._static_cast(sd.reshape(-1, 3), o.reshape(-1, 3))
        self.sub_rays_cast += sub.count.size
        n = fp.SAMPLES
        agree = mr.agreeing(sub.target_index.reshape(cand.size, n, -1), h.target_index[cand])
        mixed = np.flatnonzero(~agree)
        if mixed.size == 0:
            return
        rows = (mixed[:, None] * n + np.arange(n)).ravel()        # the mixed pixels' samples
        cols = [a[rows].reshape(mixed.size, n, -1) for a in
                (sub.range_m, sub.incidence_rad, sub.reflectivity, sub.radial_velocity_mps,
                 sub.transmission, sub.target_index)]
        for j, entry in zip(mixed, mr.mix_samples(cols, self.range_bin_m(), self.max_hits)):
            key = int(keys[cand[j]])
            self._mixed[key] = entry
            self._hits_store.add_mixed(key // 4096, key % 4096, entry)

    def _hits(self, rows, cols, t_s, footprint: bool = True):
        """(7 flat hit arrays, beam index) of beams at (rows, cols) fired at scene times ``t_s``."""
        cat, beam = self._static_hits(np.asarray(rows), np.asarray(cols), footprint)
        if self._motion.any_moving and len(rows):
            t = np.zeros(len(rows)) if t_s is None else np.broadcast_to(np.asarray(t_s, np.float64), (len(rows),))
            mov = motion.cast_moving(self.scene, self._motion, self.optics.directions(rows, cols), t)
            self.moving_rays_cast += len(rows)
            cat, beam = motion.merge(cat, beam, mov, self._motion.transmission, self.max_hits)
        return cat, beam

    def _static_hits(self, rows: np.ndarray, cols: np.ndarray, footprint: bool):
        """(7 flat hit arrays, beam index) of the static scene: each beam's stored hits, gathered
        from the store in one pass (a pixel's averages and the beams of a switch transition repeat
        pixels; per-beam Python work cost ~0.1 ms a trigger, per-pixel tuples ~0.3 ms a read)."""
        if len(rows) == 0:
            return [np.zeros(0) for _ in range(7)], np.zeros(0, np.intp)
        self._cast_pixels(rows, cols)
        return self._hits_store.gather(rows, cols, footprint)

    def beam_hits(self, rows, cols, transmission, chirp=None, t_s=None) -> BeamHits:
        """Beat tones of beams lit at (rows, cols) with switch-path transmissions ``transmission``;
        ``chirp``: each beam's chirp (trigger) index, which decorrelates speckle on moving targets;
        ``t_s``: each beam's scene time (s since the run's first trigger; None: 0), where moving
        targets are."""
        rows = np.asarray(rows)
        cols = np.asarray(cols)
        trans = np.asarray(transmission, dtype=np.float64)
        cat, beam = self._hits(rows, cols, t_s)
        total = int(beam.size)
        if total == 0:
            z = np.zeros(0)
            return BeamHits(np.zeros(0, np.int64), z, z, z, z, np.zeros(0, np.int64))
        rng_m, inc, rho, vel, chain, tgt, weight = cat
        first = np.searchsorted(beam, beam, side="left")   # hits are grouped by beam, nearest first
        ret_idx = np.arange(total) - first
        p = self.link
        p_rx = (p.received_power_w(rng_m, reflectivity=rho, incidence_rad=inc)
                * chain**2 * trans[beam] ** 2)
        amp = p.tia_gain_v_per_a * p.i_ac_a(p_rx) * weight  # weight < 1: part of a mixed pixel
        phase = None
        tgt = tgt.astype(np.int64)
        rough = self._speckle[tgt] if self._speckle.any() else np.zeros(total, bool)
        if rough.any():
            ch = np.zeros(total, np.int64) if chirp is None else np.asarray(chirp, np.int64)[beam]
            ch = np.where(self._moving[tgt], ch, 0)  # a static surface keeps its speckle
            a, ph = speckle_factors(self.seed, rows[beam], cols[beam], tgt, ch)
            amp = np.where(rough, amp * a, amp)
            phase = np.where(rough, ph, np.nan)
        tau = 2.0 * (rng_m + self.zero_offset_m) / C_M_PER_S   # LO -> lens path z0 is in every round trip
        n_mixed = int(self.is_mixed(rows, cols).sum()) if self._mixed else 0
        return BeamHits(beam=beam, range_m=rng_m, tau_s=tau, amplitude_v=amp,
                        velocity_mps=vel, return_index=ret_idx, speckle_phase_rad=phase,
                        mixed_beams=n_mixed)

    def ground_truth(self, rows, cols, t_s=None, measured_m=None) -> np.ndarray:
        """Range of the central ray's first hit per pixel (inf where nothing is hit): the scan tests'
        truth; with ``t_s`` (per pixel, s since the run's first trigger) moving targets are where
        they are then. The geometric lens -> surface distance along the TRUE beam (no zero offset).

        ``measured_m`` (per pixel): on a MIXED pixel (:meth:`is_mixed`) the truth is instead the
        footprint's return, or blend of returns within a range bin, nearest to the measurement
        (:func:`sim_devices.world.mixed_returns.nearest_truth`): the surface the point came from."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        cat, beam = self._hits(rows, cols, t_s, footprint=False)
        out = np.full(len(rows), np.inf)
        first = np.r_[True, beam[1:] != beam[:-1]] if beam.size else np.zeros(0, bool)
        out[beam[first]] = cat[0][first]
        if measured_m is None or not self._mixed:
            return out
        meas = np.broadcast_to(np.asarray(measured_m, np.float64), (len(rows),))
        keys = rows.astype(np.int64) * 4096 + cols.astype(np.int64)
        for i in np.flatnonzero(self.is_mixed(rows, cols)):
            ranges = np.r_[self._mixed[int(keys[i])][0], out[i]]   # + the central ray's (moving) hit
            out[i] = mr.nearest_truth(float(meas[i]), ranges, self.range_bin_m())
        return out
