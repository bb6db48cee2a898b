"""The few signal-processing steps the diagnosis takes, in numpy alone.

`htm diagnose` used scipy.signal (a first-order filter, Welch's spectrum) and scipy.ndimage
(running extremes, a running median) for four one-line steps; importing those two packages cost
about 1.3 s of CPU per diagnosis — a tenth of a short record's whole diagnosis, taken from the
fit's two cores. Each function here computes what its scipy counterpart computes for the
arguments the diagnosis passes (to rounding: `tests/test_ident_dsp.py` compares them).
"""
from __future__ import annotations

import numpy as np

# Samples per block of the first-order filter's closed form: a^-j stays within float range for
# j < BLOCK while a >= exp(-2) (a lag of half a sample or longer); shorter lags run in smaller blocks.
BLOCK = 256


def first_order_lag(z: np.ndarray, a: float) -> np.ndarray:
    """y[n] = a·y[n-1] + (1 − a)·z[n] from y[-1] = 0 (scipy.signal.lfilter([1 - a], [1, -a], z)),
    0 <= a < 1: within a block of `L` samples, y[n0 + j] = a^(j+1)·y[n0 − 1] + (1 − a)·a^j·Σ_{i<=j} a^-i·z[n0 + i]."""
    z = np.asarray(z, dtype=float)
    n = len(z)
    out = np.empty(n)
    if n == 0:
        return out
    if a <= 0.0:
        out[:] = (1.0 - a) * z
        return out
    # a^-(L-1) <= 1e150: the scaled sums keep their precision
    block = int(max(1, min(BLOCK, 345.0 / max(-np.log(a), 1e-12))))
    j = np.arange(block)
    up, down = a ** (-j.astype(float)), a ** j.astype(float)
    carry = 0.0
    for s in range(0, n, block):
        m = min(block, n - s)
        acc = np.cumsum(z[s:s + m] * up[:m])
        out[s:s + m] = (1.0 - a) * down[:m] * acc + carry * down[:m] * a
        carry = float(out[s + m - 1])
    return out


def welch(x: np.ndarray, fs: float, nperseg: int) -> tuple[np.ndarray, np.ndarray]:
    """Welch's power spectral density as scipy.signal.welch(x, fs, nperseg=nperseg) with its
    defaults: a periodic Hann window, half-overlapping segments, each segment's mean removed, the
    mean of the segments' one-sided densities. Returns (frequencies, density)."""
    x = np.asarray(x, dtype=float)
    nperseg = min(int(nperseg), len(x))
    step = nperseg - nperseg // 2
    win = 0.5 - 0.5 * np.cos(2.0 * np.pi * np.arange(nperseg) / nperseg)
    starts = np.arange(0, len(x) - nperseg + 1, step)
    segs = np.lib.stride_tricks.sliding_window_view(x, nperseg)[starts]
    segs = segs - segs.mean(axis=1, keepdims=True)
    spec = np.abs(np.fft.rfft(segs * win, axis=1)) ** 2
    pxx = spec.mean(axis=0) / (fs * float(np.sum(win * win)))
    if nperseg % 2:
        pxx[1:] *= 2.0
    else:
        pxx[1:-1] *= 2.0
    return np.fft.rfftfreq(nperseg, 1.0 / fs), pxx


def _running(x: np.ndarray, w: int, op: np.ufunc) -> np.ndarray:
    """`op` (np.maximum or np.minimum) over the window [i − w//2, i + w//2] of every sample, in
    O(n) (van Herk / Gil–Werman: prefix and suffix extremes of blocks of w); the window clipped
    at the ends."""
    x = np.asarray(x, dtype=float)
    n, h = len(x), w // 2
    if w <= 1 or n == 0:
        return x.copy()
    fill = -np.inf if op is np.maximum else np.inf
    total = n + 2 * h
    nb = -(-total // w)
    pad = np.full(nb * w, fill)
    pad[h:h + n] = x
    blocks = pad.reshape(nb, w)
    pre = op.accumulate(blocks, axis=1).ravel()
    suf = op.accumulate(blocks[:, ::-1], axis=1)[:, ::-1].ravel()
    i = np.arange(n)
    return op(suf[i], pre[i + w - 1])


def running_max(x: np.ndarray, w: int) -> np.ndarray:
    """The largest sample within w//2 of each (scipy.ndimage.maximum_filter1d(x, w), w odd, away
    from the ends; at the ends the window is cut short)."""
    return _running(x, w, np.maximum)


def running_min(x: np.ndarray, w: int) -> np.ndarray:
    """The smallest sample within w//2 of each (scipy.ndimage.minimum_filter1d, as running_max)."""
    return _running(x, w, np.minimum)


def running_median(x: np.ndarray, w: int) -> np.ndarray:
    """The median of the w samples about each, the ends extended with the end samples
    (scipy.ndimage.median_filter(x, size=w, mode="nearest"), w odd)."""
    x = np.asarray(x, dtype=float)
    if w <= 1 or len(x) == 0:
        return x.copy()
    h = w // 2
    padded = np.concatenate([np.full(h, x[0]), x, np.full(w - 1 - h, x[-1])])
    out = np.empty(len(x))
    view = np.lib.stride_tricks.sliding_window_view(padded, w)
    for s in range(0, len(x), 4096):  # in slabs: the partition copies each window
        out[s:s + 4096] = np.median(view[s:s + 4096], axis=1)
    return out
