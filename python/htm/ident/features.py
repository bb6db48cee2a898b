"""Residual diagnostics for `htm diagnose`: noise floors, residual features, lags, whiteness."""
from __future__ import annotations

from typing import Mapping

import numpy as np

from htm.core import CHANNELS

UNITS = {"y": "m", "v": "m/s", "p_a": "Pa", "p_b": "Pa", "p_s": "Pa", "f": "N"}
# Declared sensor resolution keys per channel (DATA_FORMAT `sensors` block).
_RESOLUTION_KEYS = ("resolution_m", "resolution_m_s", "resolution_pa", "resolution_n", "resolution")

# Low-pass window over which a residual counts as "systematic" (s).
SMOOTH_S = 0.04


def measured_channels(columns: Mapping[str, np.ndarray]) -> list[str]:
    """The channels of DATA_FORMAT's `y, v, p_a, p_b, p_s, f` that the record holds."""
    return [c for c in CHANNELS if c in columns]


def _quantum(x: np.ndarray) -> float:
    """Smallest step a quantized signal takes (0 when it looks continuous)."""
    d = np.abs(np.diff(x[np.isfinite(x)]))
    d = d[d > 0]
    if len(d) < 10:
        return 0.0
    q = float(np.min(d))
    # A quantized signal moves in integer multiples of its quantum.
    ratio = d[: 2000] / q
    return q if np.median(np.abs(ratio - np.round(ratio))) < 0.02 else 0.0


def noise_floor(x: np.ndarray, resolution: float | None = None) -> float:
    """Standard deviation of a channel's measurement noise [channel unit].

    From the second differences (a smooth signal's are near zero, white noise's have variance
    6 sigma^2), made robust with the median absolute deviation; never below the quantization
    noise q/sqrt(12) of the declared or observed resolution q, nor below 1e-5 of the span.
    """
    x = np.asarray(x, dtype=float)
    d2 = np.diff(x, n=2)
    d2 = d2[np.isfinite(d2)]
    sigma = 1.4826 * float(np.median(np.abs(d2 - np.median(d2)))) / np.sqrt(6.0) if len(d2) else 0.0
    q = max(resolution or 0.0, _quantum(x))
    sigma = max(sigma, q / np.sqrt(12.0))
    # Below ~1e-5 of the channel's span the re-simulation's own accuracy (rtol 1e-4 on the
    # state) is the limit, even for a noise-free record.
    span = float(np.nanmax(x) - np.nanmin(x)) if np.any(np.isfinite(x)) else 0.0
    return max(sigma, MIN_RELATIVE * span, 1e-12)


MIN_RELATIVE = 1e-5


def declared_noise(meta: Mapping, channel: str) -> float | None:
    """The `sensors.<channel>.noise_std` value of the metadata (sensor datasheet), if any."""
    s = (meta.get("sensors") or {}).get(channel) or {}
    v = s.get("noise_std")
    return float(v) if isinstance(v, (int, float)) and v > 0 else None


def reading_noise(meta: Mapping, channel: str, x: np.ndarray) -> float:
    """The noise of a channel's reading [channel unit]: a declared `noise_std` (the sensor's white
    noise, DATA_FORMAT.md) with the quantization noise q/sqrt(12) of its declared resolution q added
    in quadrature (the reading is the noisy signal quantized: both are in it, and a quantum far
    above the declared noise is most of it); else estimated from the record (`noise_floor`)."""
    declared, q = declared_noise(meta, channel), declared_resolution(meta, channel)
    if declared is None:
        return noise_floor(x, q)
    return float(np.hypot(declared, (q or 0.0) / np.sqrt(12.0)))


def declared_resolution(meta: Mapping, channel: str) -> float | None:
    """The quantum of a channel's reading from the metadata: `sensors.<channel>.resolution_*`,
    else `bits` over the declared `range_*` ([min, max]), if any."""
    s = (meta.get("sensors") or {}).get(channel) or {}
    for k in _RESOLUTION_KEYS:
        if isinstance(s.get(k), (int, float)) and s[k] > 0:
            return float(s[k])
    bits = s.get("bits")
    rng = s.get("range_pa", s.get("range_n", s.get("range")))
    if isinstance(bits, (int, float)) and 1 <= bits <= 64 and isinstance(rng, (list, tuple)) and len(rng) == 2:
        try:
            span = float(rng[1]) - float(rng[0])
        except (TypeError, ValueError):
            return None
        if np.isfinite(span) and span > 0:
            return span / 2.0 ** float(bits)
    return None


def smooth(x: np.ndarray, n: int) -> np.ndarray:
    """Centred moving average over `n` samples (NaN-tolerant)."""
    if n <= 1:
        return np.asarray(x, dtype=float)
    x = np.asarray(x, dtype=float)
    ok = np.isfinite(x)
    k = np.ones(n)
    num = np.convolve(np.where(ok, x, 0.0), k, mode="same")
    den = np.convolve(ok.astype(float), k, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / den


def systematic_ratio(residual: np.ndarray, sigma: float, rate_hz: float) -> float:
    """Size of the residual's non-noise part over the noise floor: the larger of the low-passed
    residual's RMS (slow errors; ~1/sqrt(window) for white noise) and the RMS left after the
    noise variance is taken out (fast errors such as a delay; ~0 for white noise), both over
    sigma. Above 1: the model's error exceeds the sensor noise."""
    r = np.asarray(residual, dtype=float)
    r = r[np.isfinite(r)]
    if not len(r):
        return 0.0
    n = max(1, int(round(SMOOTH_S * rate_hz)))
    s = smooth(r, n)
    slow = float(np.sqrt(np.mean(s**2)))
    fast = float(np.sqrt(max(0.0, np.mean(r**2) - sigma**2)))
    return float(max(slow, fast / FAST_SHARE) / sigma)  # a plain float: the log a person reads shows no numpy repr


# The part of the residual beyond the noise counts as systematic above this share of sigma.
FAST_SHARE = 0.6


def lag_samples(measured: np.ndarray, predicted: np.ndarray, max_lag: int) -> float:
    """Lag of `measured` behind `predicted` by cross-correlation of their differences [samples],
    refined by a parabola through the peak; positive = the measurement is late."""
    a = np.diff(np.nan_to_num(measured - np.nanmean(measured)))
    b = np.diff(np.nan_to_num(predicted - np.nanmean(predicted)))
    if not (np.any(a) and np.any(b)):
        return 0.0
    lags = np.arange(-max_lag, max_lag + 1)
    n = len(a)
    cc = np.array([np.dot(a[max(0, k):n + min(0, k)], b[max(0, -k):n - max(0, k)]) for k in lags])
    i = int(np.argmax(cc))
    if 0 < i < len(cc) - 1:
        den = cc[i - 1] - 2 * cc[i] + cc[i + 1]
        frac = 0.5 * (cc[i - 1] - cc[i + 1]) / den if den < 0 else 0.0
        return float(lags[i] + frac)
    return float(lags[i])


def regressors(columns: Mapping[str, np.ndarray], rate_hz: float) -> dict[str, np.ndarray]:
    """Signals a residual is tested against (DATA_FORMAT columns in, SI arrays out)."""
    y = np.asarray(columns["y"], dtype=float)
    dt = 1.0 / rate_hz
    v = np.asarray(columns["v"], dtype=float) if "v" in columns else np.gradient(smooth(y, 5), dt)
    out = {
        "constant": np.ones_like(y),
        "y": y - np.nanmean(y),
        "v": v,
        "sign(v)": np.tanh(v / max(1e-3, 0.05 * float(np.nanstd(v)))),
    }
    # the command: the valve's `u`, else the position reference of a machine that closes its own loop
    cmd = columns.get("u", columns.get("y_ref"))
    if cmd is not None:
        u = np.asarray(cmd, dtype=float)
        out |= {
            "du/dt": np.gradient(u, dt),
            "sign(du/dt)": np.sign(smooth(np.gradient(u, dt), 3)),
            "small |u|": (np.abs(u) < 0.1 * max(1e-6, float(np.nanmax(np.abs(u))))).astype(float),
            "u": u,
        }
    if "p_a" in columns and "p_b" in columns:
        pa, pb = np.asarray(columns["p_a"], dtype=float), np.asarray(columns["p_b"], dtype=float)
        out["p_a + p_b"] = pa + pb - np.nanmean(pa + pb)
        out["load pressure"] = pa - pb
        out["(p_a + p_b) sign(v)"] = (pa + pb) * out["sign(v)"]
    return out


def correlations(residual: np.ndarray, regs: Mapping[str, np.ndarray]) -> dict[str, float]:
    """Correlation coefficient of a residual with each regressor ('constant': mean/RMS)."""
    r = np.asarray(residual, dtype=float)
    ok = np.isfinite(r)
    out: dict[str, float] = {}
    rms = float(np.sqrt(np.mean(r[ok] ** 2))) if ok.any() else 0.0
    for name, x in regs.items():
        m = ok & np.isfinite(x)
        if name == "constant":
            out[name] = float(np.mean(r[m]) / rms) if rms > 0 else 0.0
            continue
        a, b = r[m] - r[m].mean(), x[m] - x[m].mean()
        den = float(np.sqrt(np.dot(a, a) * np.dot(b, b)))
        out[name] = float(np.dot(a, b) / den) if den > 0 else 0.0
    return out
