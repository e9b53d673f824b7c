"""Whether a channel's transmitter moves, and where it is now if it does (issue 68).

Two models weigh each observation point, an interacting multiple-model filter (Blom and Bar-Shalom's IMM, its
mixing made by sampling): the static one is the channel's own particle filter (its cloud as it stood before the
point: a standing transmitter's posterior, kept by the engine's moves, searches and re-starts), the moving one a
cloud of its own here (a velocity that wanders about zero as an Ornstein-Uhlenbeck process, its speed scale a
per-particle parameter with a log-uniform prior up to `max_speed`, so the cloud learns whether a walker or a car is
followed). Both read a point's readings as the receiver gave them (their median, robust to a wild one: what the
channel's calibration learns from a mover misread as standing, offsets and a wider noise, would blur the mover;
fed the calibrated points, a walker's ellipse held it a quarter of the time), through one likelihood: each moving
particle's noise scale (log-uniform over NOISE_SCALES times the readings' sigma) and wild share, learned by the
cloud and lent to the static model, so neither model wins by its noise alone. Where the standing model misfits
raw readings it explains once corrected (a mount offset it learned, a twin mode), the estimate stays the filter's
unless the filter doubts itself (Held.standing_doubted). Each model's predictive
likelihood of a point weighs it; a Markov switch between them (a mean stay of SWITCH_S) lets a transmitter start or
stop moving at any time, and a third kind, standing and never moving (NEVER_MOVES of the standing ones at first),
lets a transmitter that has stood for long be trusted to stand: the chance it has just begun to move falls as the
standing evidence grows, and one seen to move is of the kind that may move again. The moving cloud begins on the
first point's line of bearing.

The static answer stays the channel's filter's: this watch says how probable motion is and, where it is probable,
where the moving transmitter is now, how fast it goes, and whether its range is observed at all.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from aoa_localizer.engine.points.preprocess import field_lists
from aoa_localizer.engine.types import ObservationPoint, Reading
from aoa_localizer.filters.resampling import systematic

SWITCH_S = 1800.0  # mean time a transmitter that moves at all keeps standing or moving (the switching rate)
VELOCITY_TAU_S = 120.0  # a moving transmitter's velocity decorrelates over this (a walker turns, a car takes roads)
MIN_SPEED = 0.3  # the speed-scale prior's low end (m/s): below this a transmitter is as good as standing
SPEED_DRIFT = 0.1  # a moving particle's log speed scale takes a random step of this sd at each resampling
NOISE_SCALES = (0.5, 8.0)  # the prior's range of the receiver's noise over the point's own sigma (log-uniform)
WILD_SHARES = (0.01, 0.5)  # the prior's range of the share of wild points (uniform in bearing; log-uniform)
RANGE_M = (20.0, 10_000.0)  # the start's range prior: log-uniform over these (m)
SHRINK = 0.98  # Liu-West kernel shrinkage: the resampled noise and wild shares keep their spread, gain diversity
MOVING_P = 0.8  # from this probability of motion on, the estimate is the moving model's
SURE_MOVING_P = 0.95  # and from this on it may be `tracking` (below, `poorly_determined`)
UNSURE_P = 0.3  # from this on (below MOVING_P), the estimate is the two models' mixture, never `tracking`
DOUBT_POINTS = 30  # the estimate may follow the watch while the filter doubted itself within this many points,
SURE_MOTION_P = 0.99  # or after this many points in a row with the probability of motion at least this
MOTION_YIELDS_TO_COUNT = 0.99  # a transmitter count of several this sure outranks the watch (Held.motion_said)
PRIOR_MOVING = 0.1  # the probability of motion before any reading: most transmitters DF crews hunt stand
NEVER_MOVES = 0.8  # of those standing when first heard, the share that never moves (a fixed installation)
UNOBSERVED_RATIO = 6.0  # a moving ellipse this much longer along the line of sight than across: range not observed
COMPARABLE = 2.0  # the standing model is weighed once its ellipse is at most this many times the moving one's
STATIC_SAMPLE = 1000  # places drawn from the static model's posterior to take its likelihood over
KERNEL = 0.3  # each drawn standing place moved by a Gaussian kernel of this times the bearing's width at its range

# The standing model as the watch reads it: the filter's places (N, 2), their weights, its published covariance and
# the bearing offset (ENU rad) its filter takes off the bearings
Standing = tuple[np.ndarray, np.ndarray, np.ndarray, float]


@dataclass(frozen=True)
class Motion:
    """What the watch says after a point: the probability the transmitter moves and, for the moving model, its
    place now (ENU m) with covariance, its velocity (m/s) with covariance, and whether its range is observed."""

    stamp: float
    p_moving: float
    mean: np.ndarray
    cov: np.ndarray
    velocity: np.ndarray
    velocity_cov: np.ndarray
    range_observed: bool


def mixture(p: float, mean_a: np.ndarray, cov_a: np.ndarray, mean_b: np.ndarray, cov_b: np.ndarray
            ) -> tuple[np.ndarray, np.ndarray]:
    """Mean and covariance of the mixture (1 - p) A + p B of two distributions given by their moments."""
    mean = (1.0 - p) * mean_a + p * mean_b
    da, db = mean_a - mean, mean_b - mean
    return mean, (1.0 - p) * (cov_a + np.outer(da, da)) + p * (cov_b + np.outer(db, db))


def _moments(x: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    mean = w @ x
    d = x - mean
    return mean, (d * w[:, None]).T @ d


def median_bearing(readings: Sequence[Reading]) -> ObservationPoint:
    """A point's readings as the watch reads them: the median bearing as the receiver gave it (about the first, so
    wrapping cannot split it; robust to a wild one), its sigma the median's (1.25 times the readings' own over root
    n), at their mean time and antenna place."""
    stamp, theta, _, sigmas, east, north, gps, *_ = field_lists(readings)
    n, first = len(theta), theta[0]
    turns = sorted((t - first + math.pi) % (2.0 * math.pi) - math.pi for t in theta)
    turn = turns[n // 2] if n % 2 else 0.5 * (turns[n // 2 - 1] + turns[n // 2])
    sigma = math.sqrt(sum(s * s for s in sigmas) / n)
    return ObservationPoint(sum(stamp) / n, sum(east) / n, sum(north) / n, first + turn,
                            (1.2533 if n > 2 else 1.0) * sigma / math.sqrt(n), n, sum(gps) / n)


def bearing_likelihood(place: np.ndarray, r: ObservationPoint, log_noise: np.ndarray, log_wild: np.ndarray,
                       gps_sigma_m: float = 0.0) -> np.ndarray:
    """Each place's likelihood of the bearing: Gaussian in the wrapped residual at its noise scale (and the
    antenna's GPS error seen from the place: configured and the reading's own), with its wild share (uniform in
    bearing)."""
    east, north = place[:, 0] - r.east, place[:, 1] - r.north
    residual = (r.theta - np.arctan2(north, east) + np.pi) % (2.0 * np.pi) - np.pi
    gps = math.hypot(gps_sigma_m, r.gps_sigma)
    s = np.hypot(max(r.sigma, 1e-6) * np.exp(log_noise), gps / np.maximum(np.hypot(east, north), 1.0))
    wild = np.exp(log_wild)
    return (1.0 - wild) * np.exp(-0.5 * (residual / s) ** 2) / (math.sqrt(2.0 * math.pi) * s) + wild / (2.0 * math.pi)


def switched(p_moving: float, p_never: float, dt: float) -> tuple[float, float]:
    """The Markov switch over dt of a transmitter of one of two kinds: one that never moves (probability p_never)
    and one that stands and moves in turn, a mean SWITCH_S each way (p_moving that it moves now). Returns the
    probability of motion after the switch and the share of it that has just started moving."""
    switch = -math.expm1(-dt / SWITCH_S)
    standing = max(0.0, 1.0 - p_never - p_moving)
    prior_moving = p_moving * (1.0 - switch) + standing * switch
    return prior_moving, standing * switch / max(prior_moving, 1e-12)


def weighed(p_moving: float, p_never: float, evidence_s: float, evidence_m: float) -> tuple[float, float]:
    """Bayes' rule over the two models' predictive likelihoods of a point: the new probabilities of motion and of
    a transmitter that never moves (both standing kinds read the point by the standing model); unchanged where
    the evidence is no number."""
    total = (1.0 - p_moving) * evidence_s + p_moving * evidence_m
    if not (total > 0.0 and math.isfinite(total)):
        return p_moving, p_never
    return float(np.clip(p_moving * evidence_m / total, 1e-9, 1.0 - 1e-9)), p_never * evidence_s / total


class MotionWatch:
    """The moving cloud, begun on the first point's line of bearing, and the probability of motion: `step(point,
    static)` reads one observation point against it and against the standing model `static` (the channel filter's
    places, weights and published covariance before the point; None while it has none: then only the moving cloud
    learns) and returns the Motion they make."""

    def __init__(self, first: ObservationPoint, max_speed: float, rng: np.random.Generator, gps_sigma_m: float = 0.0,
                 n: int = 1000):
        self.rng, self.n, self.max_speed, self.gps_sigma_m = rng, n, max_speed, gps_sigma_m
        self.stamp = first.stamp
        self.antenna = np.array([first.east, first.north])
        self.p_moving = PRIOR_MOVING
        self.p_never = NEVER_MOVES * (1.0 - PRIOR_MOVING)  # standing, of the kind that never moves
        distance = np.exp(self._log_uniform(RANGE_M))
        ray = first.theta + 3.0 * first.sigma * rng.standard_normal(n)
        self.place = np.column_stack([first.east + distance * np.cos(ray), first.north + distance * np.sin(ray)])
        self.log_speed = self._log_uniform((MIN_SPEED, max_speed))
        self.velocity = np.exp(self.log_speed)[:, None] * rng.standard_normal((n, 2))
        self.log_noise = self._log_uniform(NOISE_SCALES)
        self.log_wild = self._log_uniform(WILD_SHARES)
        self.weights = np.full(n, 1.0 / n)

    def _log_uniform(self, bounds: tuple[float, float]) -> np.ndarray:
        return self.rng.uniform(math.log(bounds[0]), math.log(bounds[1]), self.n)

    def step(self, r: ObservationPoint, static: Standing | None) -> Motion:
        """One point: the models mixed by the switch, the moving cloud moved on to the point's time, and both
        weighed by the point's bearing."""
        dt = max(0.0, r.stamp - self.stamp)
        self.stamp, self.antenna = r.stamp, np.array([r.east, r.north])
        prior_moving, came = switched(self.p_moving, self.p_never, dt)
        places = self._sample(static, r)
        if places is not None:
            self._mix(came, places)
        self._predict(dt)
        lik_m = bearing_likelihood(self.place, r, self.log_noise, self.log_wild, self.gps_sigma_m)
        if places is not None and static is not None and self._comparable(static[2]):
            # the static places read with the moving cloud's noise and wild shares (one likelihood for both)
            lend = self.rng.permutation(systematic(self.weights, self.rng, places.shape[0]))
            # the standing model reads the bearing turned by the offset its filter learned; the moving one as given:
            # a standing transmitter with an offset and a mover whose drift was read as one are told apart
            turned = replace(r, theta=r.theta - static[3]) if static[3] else r
            evidence_s = float(bearing_likelihood(places, turned, self.log_noise[lend], self.log_wild[lend],
                                                  self.gps_sigma_m).mean())
            evidence_m = float(self.weights @ lik_m)
            self.p_moving, self.p_never = weighed(prior_moving, self.p_never, evidence_s, evidence_m)
        self._reweigh(lik_m)
        return self.motion()

    def _comparable(self, static_cov: np.ndarray) -> bool:
        """Whether the standing model has learned the place as far as the moving cloud has (its ellipse no more
        than COMPARABLE times as wide): a filter that has just started, its ellipse widened for the offsets and noise
        it has not yet learned, predicts a bearing no worse than a mover would but more loosely, and motion would
        win by that alone."""
        _, cov = _moments(self.place, self.weights)
        return float(np.trace(static_cov)) <= COMPARABLE ** 2 * float(np.trace(cov))

    def _sample(self, static: Standing | None, r: ObservationPoint) -> np.ndarray | None:
        """STATIC_SAMPLE places from the standing model's posterior: its cloud resampled by weight, each moved by a
        local kernel, KERNEL times the bearing's width at its range (a cloud just resampled may be a few copies of
        one place; a kernel of the whole ellipse would smear the modes of a cloud that has two into one wide
        blur, which predicts so loosely that motion wins); None without one."""
        if static is None:
            return None
        places, weights = np.asarray(static[0], float), np.asarray(static[1], float)
        total = weights.sum()
        if places.shape[0] == 0 or not (total > 0.0 and math.isfinite(total)):
            return None
        picked = places[systematic(weights / total, self.rng, STATIC_SAMPLE)]
        width = KERNEL * max(r.sigma, 1e-6) * np.hypot(picked[:, 0] - r.east, picked[:, 1] - r.north)
        return picked + width[:, None] * self.rng.standard_normal((STATIC_SAMPLE, 2))

    def motion(self) -> Motion:
        """The moving model's place, velocity and whether the range is observed; the probability of motion."""
        mean, cov = _moments(self.place, self.weights)
        velocity, velocity_cov = _moments(self.velocity, self.weights)
        return Motion(self.stamp, self.p_moving, mean, cov, velocity, velocity_cov, self._observed(mean, cov))

    def _observed(self, mean: np.ndarray, cov: np.ndarray) -> bool:
        """Whether the moving place's ellipse is no needle along the last line of sight (bearings alone give no range
        to a mover until the observer turns across it)."""
        values, vectors = np.linalg.eigh(cov)
        if values[0] <= 0.0:
            return False
        sight = mean - self.antenna
        along = vectors[:, 1] @ sight / max(1e-9, float(np.hypot(*sight)))
        return not (values[1] / values[0] > UNOBSERVED_RATIO ** 2 and abs(along) > 0.9)

    def _mix(self, came_share: float, static: np.ndarray) -> None:
        """The IMM's interaction into the moving model by sampling: a share of its particles are standing ones
        that start moving now (a place from the static cloud, a velocity from their speed scale). The static model
        is the channel's filter, which keeps its own."""
        came = np.flatnonzero(self.rng.random(self.n) < came_share)
        if came.size:
            self.place[came] = static[self.rng.integers(0, static.shape[0], came.size)]
            self.velocity[came] = np.exp(self.log_speed[came])[:, None] * self.rng.standard_normal((came.size, 2))

    def _predict(self, dt: float) -> None:
        """The moving cloud over dt: the place by the mean velocity over the step, the velocity an OU step."""
        if dt <= 0.0:
            return
        a = math.exp(-dt / VELOCITY_TAU_S)
        v1 = a * self.velocity + (np.exp(self.log_speed)[:, None] * math.sqrt(1.0 - a * a)
                                  * self.rng.standard_normal((self.n, 2)))
        self.place = self.place + 0.5 * (self.velocity + v1) * dt
        self.velocity = v1

    def _reweigh(self, lik: np.ndarray) -> None:
        """The weights times the likelihoods; resampled (systematic) once the effective size falls under half, the
        static parameters then spread again (the noise and wild shares by a Liu-West kernel, the speed scale by a
        random step: a speed may change, and it never collapses)."""
        w = self.weights * lik
        total = w.sum()
        if not (total > 0.0 and math.isfinite(total)):
            return
        self.weights = w / total
        if 1.0 / float(self.weights @ self.weights) >= 0.5 * self.n:
            return
        keep = systematic(self.weights, self.rng)
        self.place, self.velocity = self.place[keep], self.velocity[keep]
        self.log_speed, self.log_noise, self.log_wild = self.log_speed[keep], self.log_noise[keep], self.log_wild[keep]
        self.weights = np.full(self.n, 1.0 / self.n)
        self.log_noise = self._liu_west(self.log_noise, NOISE_SCALES)
        self.log_wild = self._liu_west(self.log_wild, WILD_SHARES)
        self.log_speed = np.clip(self.log_speed + SPEED_DRIFT * self.rng.standard_normal(self.n),
                                 math.log(MIN_SPEED), math.log(self.max_speed))

    def _liu_west(self, x: np.ndarray, bounds: tuple[float, float]) -> np.ndarray:
        jitter = math.sqrt(1.0 - SHRINK ** 2) * x.std() * self.rng.standard_normal(x.size)
        return np.clip(SHRINK * x + (1.0 - SHRINK) * x.mean() + jitter, math.log(bounds[0]), math.log(bounds[1]))
