"""a–N input: the test setup (specimen + constant-amplitude load), reading and checking a–N tables."""
from __future__ import annotations

import csv
import io
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from htm import core
from htm.errors import RecordError, SpecError
from htm.inputs import missing, read_text

GEOMETRIES = ("ct", "mt")
R_LO, R_HI = core.LOAD_R_RATIO_RANGE  # a load's stress ratios (the core's: E647 data, life prediction)


@dataclass(frozen=True)
class Setup:
    """Specimen and constant-amplitude load of an a–N record.

    Attributes
    ----------
    geometry : str
        ``"ct"`` (a from the load line) or ``"mt"`` (a is the half crack length).
    width_m, thickness_m : float
        Specimen width W and thickness B [m].
    pmax_n : float
        Maximum force [N].
    r_ratio : float
        Stress ratio R = Pmin/Pmax [-].
    yield_strength_pa : float, optional
        Yield strength [Pa]; enables the E647 size criterion.
    """

    geometry: str
    width_m: float
    thickness_m: float
    pmax_n: float
    r_ratio: float
    yield_strength_pa: float | None = None

    def __post_init__(self) -> None:
        if self.geometry not in GEOMETRIES:
            raise SpecError(f"geometry `{self.geometry}` is unknown: use ct or mt")
        for name, v in (("width_m", self.width_m), ("thickness_m", self.thickness_m)):
            if not (np.isfinite(v) and v > 0):
                raise SpecError(f"{name} = {v} must be a positive length in metres")
            if v > 2.0:
                raise SpecError(f"{name} = {v} m looks like millimetres (specimens are under 2 m); "
                                f"give metres, e.g. {v / 1000:g}")
        if self.thickness_m > self.width_m:
            raise SpecError(f"thickness_m = {self.thickness_m} exceeds width_m = {self.width_m}")
        if not (np.isfinite(self.r_ratio) and R_LO <= self.r_ratio < R_HI):
            raise SpecError(f"r_ratio = {self.r_ratio} is out of range: allowed [{R_LO:g}, {R_HI:g})")
        if not (np.isfinite(self.pmax_n) and self.pmax_n > 0):
            raise SpecError(f"maximum force pmax_n = {self.pmax_n} N must be positive (loads are tension-positive)")
        if self.yield_strength_pa is not None and not (self.yield_strength_pa > 1e6):
            raise SpecError(f"yield_strength_pa = {self.yield_strength_pa} must be in Pa (> 1e6)")

    @classmethod
    def from_loads(cls, geometry: str, width_m: float, thickness_m: float, *, r_ratio: float,
                   delta_p_n: float | None = None, pmax_n: float | None = None,
                   yield_strength_pa: float | None = None) -> Setup:
        """Build from ΔP [N] or Pmax [N] (exactly one) and R."""
        if (delta_p_n is None) == (pmax_n is None):
            raise SpecError("give exactly one of delta_p_n (force range) or pmax_n (maximum force)")
        if not (np.isfinite(r_ratio) and R_LO <= r_ratio < R_HI):
            raise SpecError(f"r_ratio = {r_ratio} is out of range: allowed [{R_LO:g}, {R_HI:g})")
        if delta_p_n is not None:
            if not (np.isfinite(delta_p_n) and delta_p_n > 0):
                raise SpecError(f"force range delta_p_n = {delta_p_n} N must be positive")
            pmax_n = core.pmax_from_delta_p(delta_p_n, r_ratio)
        return cls(geometry, width_m, thickness_m, float(pmax_n), r_ratio, yield_strength_pa)

    @property
    def delta_p_n(self) -> float:
        """ΔP per E647 [N] (Pmax − Pmin for R ≥ 0, Pmax for R < 0)."""
        return self.pmax_n * (1 - self.r_ratio) if self.r_ratio >= 0 else self.pmax_n

    @property
    def a_range_m(self) -> tuple[float, float]:
        """Crack sizes [m] over which the E647 ΔK expression is valid."""
        return core.a_range(self.geometry, self.width_m, self.thickness_m)

    @property
    def a_geometry_max_m(self) -> float:
        """Largest physically possible crack size [m] (W for C(T), W/2 for M(T))."""
        return self.width_m if self.geometry == "ct" else self.width_m / 2

    def kmax(self, a_m: np.ndarray) -> np.ndarray:
        """Kmax [Pa·√m] at crack sizes a [m] (inside the valid range)."""
        return core.stress_intensity(self.geometry, self.width_m, self.thickness_m, np.ascontiguousarray(a_m, float), self.pmax_n)

    def delta_k(self, a_m: np.ndarray) -> np.ndarray:
        """ΔK [Pa·√m] at crack sizes a [m] (inside the valid range)."""
        return core.stress_intensity(self.geometry, self.width_m, self.thickness_m, np.ascontiguousarray(a_m, float), self.delta_p_n)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["delta_p_n"] = self.delta_p_n
        return d


@dataclass
class CrackData:
    """One specimen's a–N record, in test order.

    Attributes
    ----------
    specimen : str
        The specimen's name.
    cycles : ndarray
        Cycle count N at each reading.
    a_m : ndarray
        Crack size a [m] at each reading.
    """

    specimen: str
    cycles: np.ndarray
    a_m: np.ndarray


def read_a_n(path: str | Path, a_mm_column: str | None = None) -> list[CrackData]:
    """Read an a–N CSV file.

    Parameters
    ----------
    path : str or Path
        CSV with columns ``cycles`` and ``a_m`` [m] (or ``a_mm``, millimetres, converted to m),
        optionally ``specimen``.
    a_mm_column : str, optional
        The column holding a in millimetres when it is not named ``a_mm`` (e.g. Virkler's
        ``a_half_crack_mm``).

    Returns
    -------
    list of CrackData
        One per specimen, in file order (crack size in m). Raises RecordError naming the file,
        the line and the column of what is wrong (not text, no rows, a missing or misspelt
        column, a value that is not a finite number).
    """
    path = Path(path)
    text = read_text(path, "a–N table (CSV)", RecordError)
    table = list(csv.reader(io.StringIO(text, newline="")))
    if not table or not any(table):
        raise RecordError(f"{path}: the a–N table is empty (a header `cycles,a_m[,specimen]`, then a row per reading)")
    cols = [c.strip() for c in table[0]]
    body = [(i, r) for i, r in enumerate(table[1:], start=2) if r and any(x.strip() for x in r)]
    if not body:
        raise RecordError(f"{path}: a header ({', '.join(cols)}) but no data rows")
    if a_mm_column and a_mm_column in cols:
        cols = ["a_mm" if c == a_mm_column else c for c in cols]
    if "cycles" not in cols:
        raise RecordError(f"{path}: required column `cycles` is missing{missing('cycles', cols)} (found: {', '.join(cols)})")
    if "a_m" in cols:
        acol, scale = "a_m", 1.0
    elif "a_mm" in cols:
        acol, scale = "a_mm", 1e-3
    else:
        hint = missing("a_m", cols) or missing("a_mm", cols)
        raise RecordError(f"{path}: required column `a_m` (or `a_mm`) is missing{hint} (found: {', '.join(cols)})")
    idx = {c: i for i, c in enumerate(cols)}

    def num(r: list[str], c: str, line: int) -> float:
        x = r[idx[c]].strip() if idx[c] < len(r) else ""
        try:
            v = float(x)
        except ValueError:
            raise RecordError(f"{path}: line {line}: `{c}` = {x!r} is not a number") from None
        if not np.isfinite(v):
            raise RecordError(f"{path}: line {line}: `{c}` = {x} is not a finite number")
        return v

    groups: dict[str, tuple[list[float], list[float]]] = {}
    for line, r in body:
        key = (r[idx["specimen"]] if idx["specimen"] < len(r) else "").strip() if "specimen" in idx else "1"
        g = groups.setdefault(key, ([], []))
        g[0].append(num(r, "cycles", line))
        g[1].append(num(r, acol, line) * scale)
    out = [CrackData(k, np.array(n), np.array(a)) for k, (n, a) in groups.items()]
    if acol == "a_m":
        amax = max(float(d.a_m.max()) for d in out)
        if amax > 1.0:
            raise RecordError(f"{path}: column `a_m` has values up to {amax:g}, which looks like millimetres; "
                              f"rename the column to `a_mm` or convert to metres")
    return out


def check_a_n(data: CrackData, setup: Setup, source: str = "input") -> None:
    """Raise RecordError if cycles decrease (equal counts from rounding are allowed) or a crack size is outside the geometry."""
    n, a = data.cycles, data.a_m
    where = f"{source}, specimen {data.specimen}"
    if len(n) < 2:
        raise RecordError(f"{where}: needs at least 2 a–N points, got {len(n)}")
    if not (np.all(np.isfinite(n)) and np.all(np.isfinite(a))):
        raise RecordError(f"{where}: cycles and crack sizes must be finite numbers")
    if np.any(n < 0):
        raise RecordError(f"{where}: negative cycle count {n[n < 0][0]:g}")
    bad = np.nonzero(np.diff(n) < 0)[0]
    if bad.size:
        i = int(bad[0])
        raise RecordError(f"{where}: cycles must not decrease (non-monotonic), but point {i + 2} has N = {n[i + 1]:g} "
                          f"after N = {n[i]:g}")
    amax = setup.a_geometry_max_m
    if np.any(a <= 0) or np.any(a >= amax):
        i = int(np.nonzero((a <= 0) | (a >= amax))[0][0])
        hint = ""
        if a[i] >= amax and a[i] * 1e-3 < amax:
            hint = " (looks like millimetres: use column `a_mm`)"
        raise RecordError(f"{where}: crack size a = {a[i]:g} m at point {i + 1} is outside the "
                          f"{setup.geometry.upper()} geometry (0, {amax:g}) m{hint}")
    lo, hi = setup.a_range_m
    inside = (a >= lo) & (a <= hi)
    if not np.any(inside):
        raise RecordError(f"{where}: no crack size lies in the range where the {setup.geometry.upper()} ΔK "
                          f"expression holds, [{lo:g}, {hi:g}] m (data span {a.min():g}..{a.max():g} m)")
