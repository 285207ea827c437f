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

Hidden truths (issue 13; :mod:`sim_devices.world.tolerances`): given a ``BenchTruth``, the beams
leave along the TRUE pointing (``optics.with_pointing(truth.pointing)``: focal scale, decentre,
rotation, k1 bend eq. 4-1), and every hit's round trip is 2 (d + z0) / c, z0 the optical path from
the reference reflection (the LO) to the lens, while ``range_m`` and :meth:`World.ground_truth` stay
the geometric lens -> surface distance d along the true beam (what the scans are scored against).
The link budget uses d too: z0 is inside the instrument, it neither spreads nor attenuates the beam.

Targets move during a scan (issue 14): a beam fired at scene time t (its trigger, counted from the
run's first trigger) sees every moving target translated by v t; velocities also give the Doppler
shifts and the within-segment range drift of the synthesis. Static targets are cast once per pixel
and cached; moving ones are cast per beam at its time (sim_devices.world.motion). ``rays_cast``
counts the cached casts, ``moving_rays_cast`` the per-beam ones.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from lidard.config import Config, LaserPreset, Profile
from lidard.physics.budget import LinkParams, asd_components
from lidard.physics.constants import C_M_PER_S
from lidard.physics.optics import FpsaOptics

from . import footprint as fp
from . import motion
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


class World:
    """Scene + optics + link budget, with a per-pixel ray-cast cache."""

    def __init__(self, cfg: Config, profile: Profile, laser: LaserPreset, scene: Scene,
                 *, max_hits: int = 4, seed: int = 0, truth: BenchTruth | None = None) -> None:
        self.cfg = cfg
        self.profile = profile
        self.laser = laser
        # None: the nominal bench (what the configuration says, as before issue 13)
        self.truth = truth
        optics = profile.optics(cfg.lens, cfg.chirp.wavelength_m)
        self.optics: FpsaOptics = optics if truth is None else optics.with_pointing(truth.pointing)
        self.zero_offset_m = 0.0 if truth is None else float(truth.zero_offset_m)
        self.link: LinkParams = cfg.link_params(profile, laser)
        self.max_hits = max_hits
        self.seed = int(seed)  # speckle draws
        self.rays_cast = 0          # pixels cast into the static targets (then cached)
        self.moving_rays_cast = 0   # beams cast into the moving targets, each at its own time
        self.set_scene(scene)

    def set_scene(self, scene: Scene) -> None:
        self.scene = scene
        self._cache: dict[int, tuple] = {}
        self._speckle = np.array([bool(t.speckle) for t in scene.targets], bool)
        self._moving = np.array([bool(np.any(t.velocity != 0)) for t in scene.targets], bool)
        self._motion = motion.SceneMotion.of(scene)

    # -- noise ------------------------------------------------------------------------------------
    def white_noise_asd_v(self) -> float:
        """ASD of the white noises at the ADC input (shot, RIN, thermal, ambient), V/sqrt(Hz)."""
        c = asd_components(self.link, 1.0)  # white terms do not depend on distance (P_ref >> P_rx)
        return float(np.sqrt(sum(float(c[k]) ** 2 for k in WHITE_NOISES)))

    # -- beams ------------------------------------------------------------------------------------
    def _cast_pixels(self, rows: np.ndarray, cols: np.ndarray) -> list[tuple]:
        keys = rows.astype(np.int64) * 4096 + cols.astype(np.int64)
        missing = np.unique(keys[[k not in self._cache for k in keys]]) if len(keys) else keys
        if len(missing):
            d = self.optics.directions(missing // 4096, missing % 4096)
            h = self._static_cast(d)
            self.rays_cast += len(missing)
            for i, k in enumerate(missing):
                self._cache[int(k)] = (*_entry(h, i), np.ones(int(h.count[i])))
            if self.scene.mixed_pixels:
                self._sample_footprints(missing, d)
        return [self._cache[int(k)] for k in keys]

    def _static_cast(self, d: np.ndarray):
        """Cast into the static targets, hits naming their index in the whole scene."""
        m = self._motion
        h = m.static.cast(d, max_hits=self.max_hits)
        if m.static is self.scene or m.static_index.size == 0:
            return h            # (nothing static: every slot is empty, -1)
        idx = np.where(h.target_index >= 0, m.static_index[np.maximum(h.target_index, 0)], -1)
        return replace(h, target_index=idx)

    def _footprint_radius(self, range_m):
        lens = self.profile.lenses[self.cfg.lens or self.profile.default_lens]
        return fp.footprint_radius_m(range_m, emission_w_m=self.optics.emission_w_m,
                                     focal_m=self.optics.focal_m, wavelength_m=self.optics.wavelength_m,
                                     aperture_m=lens.aperture_m)

    def _sample_footprints(self, keys: np.ndarray, d: np.ndarray) -> None:
        """Mixed pixels: re-cast the footprints that may straddle an edge (sim_devices.world.footprint)."""
        cand = np.flatnonzero(fp.edge_candidates(self._motion.static.targets, d, self._footprint_radius))
        if cand.size == 0:
            return
        first = np.array([self._cache[int(keys[i])][0][:1].tolist() or [np.inf] for i in cand]).ravel()
        probe = np.where(np.isfinite(first), first, 1e3)   # a miss: the footprint far away
        half = np.arctan(self._footprint_radius(probe) / probe)
        sub = fp.sub_ray_directions(d[cand], half)
        h = self._static_cast(sub.reshape(-1, 3))
        bin_m = C_M_PER_S / (2.0 * abs(self.cfg.chirp.excursion_hz))  # one range bin
        for j, i in enumerate(cand):
            key = int(keys[i])
            samples = [self._cache[key][:6]] + [_entry(h, j * fp.RING + s) for s in range(fp.RING)]
            mixed = fp.mix_samples(samples, bin_m, self.max_hits)
            if mixed is not None:
                self._cache[key] = mixed

    def _hits(self, rows, cols, t_s):
        """(7 flat hit arrays, beam index) of beams at (rows, cols) fired at scene times ``t_s``."""
        entries = self._cast_pixels(rows, cols)
        counts = np.fromiter((len(e[0]) for e in entries), dtype=np.int64, count=len(entries))
        beam = np.repeat(np.arange(len(entries)), counts)
        cat = [np.concatenate([e[j] for e in entries]) if len(entries) else np.zeros(0) for j in range(7)]
        if self._motion.any_moving and len(rows):
            t = np.zeros(len(rows)) if t_s is None else np.broadcast_to(np.asarray(t_s, np.float64), (len(rows),))
            mov = motion.cast_moving(self.scene, self._motion, self.optics.directions(rows, cols), t)
            self.moving_rays_cast += len(rows)
            cat, beam = motion.merge(cat, beam, mov, self._motion.transmission, self.max_hits)
        return cat, beam

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
        return BeamHits(beam=beam, range_m=rng_m, tau_s=tau, amplitude_v=amp,
                        velocity_mps=vel, return_index=ret_idx, speckle_phase_rad=phase)

    def ground_truth(self, rows, cols, t_s=None) -> np.ndarray:
        """Range of the first hit per pixel (inf where nothing is hit): the scan tests' truth; with
        ``t_s`` (per pixel, s since the run's first trigger) moving targets are where they are then.
        The geometric lens -> surface distance along the TRUE beam (no zero offset)."""
        rows, cols = np.asarray(rows), np.asarray(cols)
        cat, beam = self._hits(rows, cols, t_s)
        out = np.full(len(rows), np.inf)
        first = np.r_[True, beam[1:] != beam[:-1]] if beam.size else np.zeros(0, bool)
        out[beam[first]] = cat[0][first]
        return out


def _entry(h, i: int) -> tuple:
    """(range, incidence, reflectivity, radial velocity, transmission, target) of ray i's hits."""
    n = int(h.count[i])
    return (h.range_m[i, :n].copy(), h.incidence_rad[i, :n].copy(), h.reflectivity[i, :n].copy(),
            h.radial_velocity_mps[i, :n].copy(), h.transmission[i, :n].copy(),
            h.target_index[i, :n].astype(np.float64))
