"""The velocity-jitter yardstick (benchmarks/validation/velocity_jitter.py): synthetic rises, no
simulation. The target is a jitter of 0.1% of the peak rise speed (2.4e-4 m/s for Hysing's 0.24),
so the yardstick must read a noise-free rise well below that and a known wobble at its size."""

import numpy as np
import pytest

from benchmarks.validation import velocity_jitter as vj

V_MAX, RISE_TIME = 0.24, 0.2  # m/s, s: v = V_MAX tanh(t / RISE_TIME), a Hysing-like start
T = np.linspace(0.0, vj.T_END, 569)  # the step count of hysing_2d at 80 cells


def height(t):
    """The centroid whose rate is v above."""
    return 0.5 + V_MAX * RISE_TIME * np.log(np.cosh(t / RISE_TIME))


def test_a_noise_free_rise_reads_far_below_the_target():
    # Measured 5.9e-5 m/s (the bins' mean against a centre value); the older reading, about the
    # slope of a quadratic through the centroid, misses the speed's curvature: 1.1e-3 m/s, 0.5% of
    # the peak, five times the target, on a rise with no jitter at all.
    assert vj.jitter(T, height(T)) < 0.5e-3 * V_MAX
    assert vj.jitter_position_window(T, height(T)) > 4e-3 * V_MAX  # the bias the docstring states
    assert vj.peak_speed(T, height(T)) == pytest.approx(V_MAX, rel=1e-3)


@pytest.mark.parametrize("amplitude", [2.4e-4, 2.4e-3])
def test_a_wobble_from_bin_to_bin_reads_at_its_size(amplitude):
    # Each bin's steps moved by +-amplitude in turn (a square wave of two bins' period): the RMS of
    # the bins' deviations is the amplitude, read within 10% (the fit follows a little of it).
    mid = 0.5 * (T[1:] + T[:-1])
    sign = np.where(np.floor((mid - vj.FROM) / vj.BIN) % 2 == 0, 1.0, -1.0)
    rate = np.diff(height(T)) / np.diff(T) + amplitude * sign
    y = np.concatenate([[height(T[0])], height(T[0]) + np.cumsum(rate * np.diff(T))])
    assert vj.jitter(T, y) == pytest.approx(amplitude, rel=0.1)


def test_steps_longer_than_a_bin_still_give_a_reading():
    # --quick's 10 cells take 26 steps of about 0.06 s, longer than a 0.025 s bin: the bins without
    # a step of their own are left out, not read as NaN.
    coarse = np.linspace(0.0, vj.T_END, 27)
    assert np.isfinite(vj.jitter(coarse, height(coarse)))
    assert np.isfinite(vj.jitter_position_window(coarse, height(coarse)))
