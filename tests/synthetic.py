"""Synthetic records with known answers, shared by the tests of periodicity.py and regimes.py: a
non-sinusoidal oscillation of period T sampled every H, its noisy, drifting and transient variants
(SIGNALS), and a run's series around a theta record (:func:`series`)."""
import numpy as np

H = 0.005                     # the default sampling interval of a run
T = 0.7
t = np.arange(0.0, 20.0, H)
#: SIGNALS draws its noise from here, three records of t.size normals; later draws continue the stream
rng = np.random.default_rng(2026)


def oscillation(t, period=T, mean=0.6, amplitude=0.1):
    """A non-sinusoidal periodic signal (three harmonics), like theta in phase-treading."""
    phase = 2 * np.pi * t / period
    return mean + amplitude * (np.sin(phase) + 0.5 * np.sin(2 * phase + 0.5) + 0.25 * np.sin(3 * phase + 1.0))


def fold(angle):
    """An angle folded into (-pi/2, pi/2], as the inclination is recorded."""
    return angle - np.pi * np.ceil(angle / np.pi - 0.5)


SIGNALS = {
    "clean": oscillation(t),
    "noise 10 %": oscillation(t) + 0.01 * rng.standard_normal(t.size),
    "noise 30 %": oscillation(t) + 0.03 * rng.standard_normal(t.size),
    "decaying transient": oscillation(t) * (1 - np.exp(-t / 2)) + 0.3 * np.exp(-t / 2) * np.cos(5 * t),
    "slow drift": oscillation(t) + 0.005 * t,
    "peaked": 0.6 + 0.2 * np.exp(-8 * (1 - np.cos(2 * np.pi * t / T))),
    "transient, noise and drift": (oscillation(t) + 0.4 * np.exp(-t / 1.5) + 0.002 * t
                                   + 0.02 * rng.standard_normal(t.size)),
}


def series(theta, pattern_speed=0.5, tank_treading=-10.0, time=t):
    """A run's series for classify: ``theta``, a pattern moving at ``pattern_speed`` tank-treading speeds."""
    v = np.full(time.size, tank_treading)
    return {"t": time, "theta": theta, "V_psi": np.full(time.size, pattern_speed * tank_treading) * 0.3,
            "V_L": np.full(time.size, pattern_speed * tank_treading) * 0.7, "tank_treading_velocity": v}
