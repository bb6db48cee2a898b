"""Records per DATA_FORMAT.md: round trips in every table format, and validation with clear errors."""
import numpy as np
import pytest

import htm
from htm.errors import RecordError
from htm.ident import Record, read_record, validate_record, write_record
from htm.params import rig_metadata, thesis_rig


def simulated_record(n=400, rate=500.0):
    p = thesis_rig()
    u = np.r_[np.full(n // 2, 0.5), np.full(n - n // 2, -0.5)]
    tr = htm.Machine(p).simulate(u, 1 / rate)
    cols = {k: tr[k] for k in ("t", "u", "y", "v", "p_a", "p_b", "p_s")}
    meta = {"sample_rate_hz": rate, "rig": rig_metadata(p), "specimen": None, "controller": None, "sensors": {}}
    return Record(cols, meta, "sim")


@pytest.mark.parametrize("kind", ["csv", "gz", "parquet"])
def test_round_trip_keeps_every_column_exactly(tmp_path, kind):
    rec = simulated_record()
    rec.columns["extra_channel"] = np.arange(len(rec.columns["t"]), dtype=float)  # unknown columns are kept
    rec.columns["v"][7] = np.nan  # a dropped sample stays a NaN
    table, meta = write_record(rec, tmp_path / "r", compress=kind == "gz", parquet=kind == "parquet")
    back = read_record(table)
    assert set(back.columns) == set(rec.columns)
    for c in rec.columns:
        np.testing.assert_array_equal(back.columns[c], rec.columns[c])
    assert back.meta["format"] == "htm-record/1" and back.meta["rig"]["stroke_m"] == 0.2
    assert validate_record(back) == ["column `v`: 1 dropped samples (NaN), longest run 1"]


def test_clean_simulated_record_validates_without_warnings():
    assert validate_record(simulated_record()) == []


def _broken(mutate):
    rec = simulated_record()
    mutate(rec)
    return rec


@pytest.mark.parametrize(
    "mutate,needle",
    [
        (lambda r: r.columns.pop("y"), "required column `y` is missing"),
        (lambda r: r.columns.__setitem__("t", np.r_[r.columns["t"][:100], r.columns["t"][100:] + 0.0005]), "not uniform"),
        (lambda r: r.columns.__setitem__("t", r.columns["t"][::-1].copy()), "does not increase"),
        (lambda r: r.meta.__setitem__("sample_rate_hz", 1000), "metadata says 1000 Hz"),
        (lambda r: r.columns.__setitem__("y", r.columns["y"] * 1e3), "looks like mm"),
        (lambda r: r.columns.__setitem__("p_a", r.columns["p_a"] / 1e5), "looks like bar or MPa"),
        (lambda r: r.columns.__setitem__("v", r.columns["v"] * 1e3), "looks like mm/s"),
        (lambda r: r.columns["p_b"].__setitem__(slice(100, 400), np.nan), "NaN samples"),
        (lambda r: r.columns.__setitem__("u", np.full_like(r.columns["u"], np.nan)), "no finite value"),
    ],
)
def test_malformed_records_are_refused_with_the_reason(mutate, needle):
    with pytest.raises(RecordError, match=needle):
        validate_record(_broken(mutate))


def test_a_three_sample_file_cannot_be_identified(tmp_path):
    (tmp_path / "tiny.csv").write_text("t,u,y\n0,0,0.1\n0.002,0,0.1\n0.004,0,0.1\n")
    (tmp_path / "tiny.json").write_text('{"format": "htm-record/1", "sample_rate_hz": 500}')
    with pytest.raises(RecordError, match="only 3 samples"):
        validate_record(read_record(tmp_path / "tiny.csv"))


def test_unreadable_inputs_give_record_errors(tmp_path):
    (tmp_path / "a.csv").write_text("t,u,y\n0,0,0.1\n0.002,x,0.1\n")
    (tmp_path / "a.json").write_text('{"format": "htm-record/1"}')
    with pytest.raises(RecordError, match=r"a.csv: line 3: column `u` = 'x' is not a number"):
        read_record(tmp_path / "a.csv")
    (tmp_path / "b.csv").write_text("t,u,y\n0,0,0.1\n")
    (tmp_path / "b.json").write_text("{not json")
    with pytest.raises(RecordError, match="not valid JSON"):
        read_record(tmp_path / "b.csv")
    (tmp_path / "c.parquet").write_bytes(b"garbage")
    (tmp_path / "c.json").write_text('{"format": "htm-record/1"}')
    with pytest.raises(RecordError, match="Parquet"):
        read_record(tmp_path / "c.parquet")
    with pytest.raises(RecordError, match="no metadata"):
        (tmp_path / "d.csv").write_text("t,u,y\n0,0,0\n")
        read_record(tmp_path / "d.csv")


def test_a_table_reads_the_same_whether_parsed_at_once_or_row_by_row(tmp_path):
    """A clean table is parsed at once; one with a dropped sample (an empty field) row by row: the
    numbers are the same either way, the dropped sample NaN, and a bad value still names its line."""
    import numpy as np

    from htm.recordfile import read_table

    rows = [f"{i * 0.002:.3f},{np.sin(i) * 1e-3:.9g},{2e6 + i:.6g}" for i in range(200)]
    clean, holed, bad = (tmp_path / n for n in ("clean.csv", "holed.csv", "bad.csv"))
    clean.write_text("t,y,p_a\n" + "\n".join(rows) + "\n")
    holed.write_text("t,y,p_a\n" + "\n".join(rows[:50] + [rows[50].rsplit(",", 1)[0] + ","] + rows[51:]) + "\n")
    bad.write_text("t,y,p_a\n" + "\n".join(rows[:7] + ["0.014,inf,2e6"] + rows[8:]) + "\n")
    a, b = read_table(clean), read_table(holed)
    assert np.isnan(b["p_a"][50]) and not np.isnan(a["p_a"]).any()
    for c in ("t", "y", "p_a"):
        keep = ~np.isnan(b[c])
        assert np.array_equal(a[c][keep], b[c][keep])
    with pytest.raises(Exception, match="line 9: column `y`"):
        read_table(bad)
