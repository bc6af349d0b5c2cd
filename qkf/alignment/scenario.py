"""Simulated vector observations for the alignment calibration (docs/alignment.md, "Simulation").

Per epoch ``t_k = k Δt`` the attitude ``C_k`` (body → inertial) is drawn uniformly over the
rotations. A star sensor reports ``per_epoch`` catalogue stars: their true body-frame directions
are uniform in its field of view (a cone of half-angle ``fov_deg`` about its boresight), their
reference vectors ``r = C_k u``. A sun sensor reports the sun, ``r = sun_direction``, at the
epochs where ``u = C_kᵀ r`` lies in its field of view. Every sensor reports
``w = normalise(Exp(θ_s)ᵀ u + σ_s n)``, ``n ~ N(0, I)``: after normalisation a rotation error of
``σ_s`` per axis perpendicular to ``w``.

Trial ``i`` of seed ``s`` draws from ``SeedSequence([s, i])``, one child stream per source
(truth, attitude, directions, noise), so a trial is reproducible on its own.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from qkf.alignment.config import AlignmentConfig
from qkf.alignment.data import Observations
from qkf.core import units
from qkf.core.so3 import exp_matrix

_STREAMS = ("truth", "attitude", "directions", "noise")


def _unit(v: tuple[float, float, float] | np.ndarray) -> np.ndarray:
    a = np.asarray(v, dtype=float)
    return a / np.linalg.norm(a)


def _basis(axis: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors completing ``axis`` to a right-handed orthonormal basis."""
    helper = np.eye(3)[int(np.argmin(np.abs(axis)))]
    e1 = np.cross(axis, helper)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(axis, e1)


def cone_directions(
    axis: np.ndarray, half_angle: float, count: int, rng: np.random.Generator
) -> np.ndarray:
    """``count`` unit vectors uniform on the spherical cap of ``half_angle`` (rad) about
    ``axis`` (count, 3)."""
    cos_t = rng.uniform(np.cos(half_angle), 1.0, count)
    sin_t = np.sqrt(np.clip(1.0 - cos_t**2, 0.0, None))
    phi = rng.uniform(0.0, 2.0 * np.pi, count)
    e1, e2 = _basis(axis)
    return (
        cos_t[:, None] * axis
        + (sin_t * np.cos(phi))[:, None] * e1
        + (sin_t * np.sin(phi))[:, None] * e2
    )


def true_alignments(cfg: AlignmentConfig, rng: np.random.Generator) -> np.ndarray:
    """True ``θ`` per sensor (S, 3) rad: the config's ``misalignment_deg``, or drawn from the
    prior; the reference is zero."""
    out = np.zeros((len(cfg.sensors), 3))
    for i, s in enumerate(cfg.sensors):
        draw = rng.normal(0.0, cfg.prior_deg_of(s) * units.DEG, 3)  # always drawn: fixed streams
        if s.name == cfg.reference:
            continue
        out[i] = draw if s.misalignment_deg is None else np.asarray(s.misalignment_deg) * units.DEG
    return out


def simulate(
    cfg: AlignmentConfig, trial: int = 0, seed: int | None = None
) -> tuple[Observations, np.ndarray]:
    """Observations of one trial and the true alignments (S, 3) rad."""
    sim = cfg.simulation
    seed = sim.seed if seed is None else seed
    streams = np.random.SeedSequence([seed, trial]).spawn(len(_STREAMS))
    g = {name: np.random.default_rng(ss) for name, ss in zip(_STREAMS, streams, strict=True)}
    theta = true_alignments(cfg, g["truth"])
    n_ep = sim.epochs
    t = np.arange(n_ep) * sim.dt_s
    attitude = Rotation.random(n_ep, random_state=g["attitude"]).as_matrix()  # (E, 3, 3)
    sun = _unit(sim.sun_direction)
    rot_t = np.swapaxes(exp_matrix(theta), -1, -2)  # Exp(θ)ᵀ per sensor
    ts, ss, us, rs = [], [], [], []
    for i, s in enumerate(cfg.sensors):
        axis = _unit(s.boresight)
        half = s.fov_deg * units.DEG
        if s.observes == "stars":
            u = cone_directions(axis, half, n_ep * s.per_epoch, g["directions"])
            ep = np.repeat(np.arange(n_ep), s.per_epoch)
            r = np.einsum("eij,ej->ei", attitude[ep], u)
        else:
            u_all = np.einsum("eji,j->ei", attitude, sun)  # C_kᵀ sun
            ep = np.flatnonzero(u_all @ axis >= np.cos(half) - 1e-12)
            u = u_all[ep]
            r = np.broadcast_to(sun, u.shape)
        ts.append(t[ep])
        ss.append(np.full(ep.size, i))
        us.append(u @ rot_t[i].T)
        rs.append(r)
    u_meas = np.concatenate(us)
    sigma = np.array([s.sigma_arcsec * units.ARCSEC for s in cfg.sensors])
    sensor = np.concatenate(ss).astype(np.int64)
    noisy = u_meas + sigma[sensor][:, None] * g["noise"].normal(size=u_meas.shape)
    t_all = np.concatenate(ts)
    order = np.lexsort((sensor, t_all))
    obs = Observations(
        names=tuple(cfg.names),
        t=t_all[order],
        sensor=sensor[order],
        w=(noisy / np.linalg.norm(noisy, axis=1, keepdims=True))[order],
        r=np.concatenate(rs)[order],
        row=np.full(t_all.size, -1, dtype=np.int64),
    )
    return obs, theta
