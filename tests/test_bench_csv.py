"""Bench CSV v1 reader and writer (docs/spec/bench-csv-v1.md, docs/bench-csv.md).

Every bad-input rule is exercised through a real file in ``tmp_path``; each refusal must
name the file path, the 1-based line number (comment lines counted) and the column.
"""

from __future__ import annotations

import csv
import io

import numpy as np
import pytest

from triadcal.io.bench_csv import (REQUIRED, BenchCSVError, format_bench_csv, read_bench_csv,
                                   write_bench_csv)
from triadcal.models.simulate import Schedule, preset_truth, simulate_campaign

# -- helpers ---------------------------------------------------------------------------


@pytest.fixture(scope="module")
def campaign():
    """A small simulated campaign (2 setpoints x 12 positions) with sd_* and n_samples."""
    schedule = Schedule(setpoints_C=(20.0, 35.0), soak_s=600.0)
    return simulate_campaign(preset_truth("ak18-quartz"), schedule=schedule, seed=3)


class Table:
    """A bench CSV split into comment lines, header and rows, for surgical edits."""

    def __init__(self, text: str):
        lines = text.splitlines()
        k = 0
        while lines[k].startswith("#"):
            k += 1
        self.comments = lines[:k]
        rows = list(csv.reader(lines[k:]))
        self.header, self.rows = rows[0], rows[1:]

    @property
    def header_line(self) -> int:
        return len(self.comments) + 1

    def line_of_row(self, r: int) -> int:
        """1-based line number of data row ``r`` (comments and header counted)."""
        return self.header_line + 1 + r

    def set(self, r: int, column: str, value: str) -> None:
        self.rows[r][self.header.index(column)] = value

    def drop_column(self, column: str) -> None:
        j = self.header.index(column)
        self.header.pop(j)
        for row in self.rows:
            row.pop(j)

    def text(self) -> str:
        buf = io.StringIO()
        for c in self.comments:
            buf.write(c + "\n")
        w = csv.writer(buf, lineterminator="\n")
        w.writerow(self.header)
        w.writerows(self.rows)
        return buf.getvalue()

    def write(self, path) -> str:
        path.write_text(self.text(), encoding="utf-8")
        return str(path)


@pytest.fixture
def table(campaign):
    t = Table(format_bench_csv(campaign))
    assert len(t.comments) >= 3, "the sample must carry comment lines so that line counting is tested"
    return t


def refused(path, line, column, *fragments) -> BenchCSVError:
    """Read ``path``, expect a BenchCSVError naming path, line and column; return it."""
    with pytest.raises(BenchCSVError) as info:
        read_bench_csv(path)
    err = info.value
    msg = str(err)
    assert msg.startswith(f"{path}:{line}"), msg
    assert err.path == str(path) and err.line == line
    assert err.column == column, msg
    if column is not None:
        assert f"'{column}'" in msg, msg
    for f in fragments:
        assert f in msg, msg
    return err


# -- the bad-input rules of bench-csv.md -------------------------------------------------


@pytest.mark.parametrize("column", REQUIRED)
def test_missing_required_column(tmp_path, table, column):
    table.drop_column(column)
    path = table.write(tmp_path / "missing.csv")
    refused(path, table.header_line, column, "missing")


@pytest.mark.parametrize("column, value", [("w_x", "abc"), ("w_z", "1.0V"), ("t_y", "--"),
                                           ("setpoint_C", "hot"), ("time_s", "12:00"),
                                           ("axis1_deg", "ninety"), ("tau_s", "30s")])
def test_non_numeric_reading(tmp_path, table, column, value):
    table.set(5, column, value)
    path = table.write(tmp_path / "text.csv")
    refused(path, table.line_of_row(5), column, "not a number", repr(value))


@pytest.mark.parametrize("column, value", [("w_y", "nan"), ("w_x", "NaN"), ("t_z", "NAN"),
                                           ("w_z", "inf"), ("time_s", "-Infinity"),
                                           ("sd_x", "inf")])
def test_nan_and_inf_are_refused(tmp_path, table, column, value):
    table.set(7, column, value)
    path = table.write(tmp_path / "nan.csv")
    refused(path, table.line_of_row(7), column, "finite")


def test_position_visited_with_no_readings(tmp_path, table):
    for c in ("w_x", "w_y", "w_z"):
        table.set(9, c, "")
    label = table.rows[9][table.header.index("position")]
    path = table.write(tmp_path / "noreadings.csv")
    refused(path, table.line_of_row(9), "w_x", "no readings", repr(label))


def test_one_missing_reading_is_an_empty_field(tmp_path, table):
    table.set(4, "w_y", "")
    path = table.write(tmp_path / "onemissing.csv")
    refused(path, table.line_of_row(4), "w_y", "empty")


@pytest.mark.parametrize("word", ["warming", "Heating", "up", ""])
def test_unknown_direction_word(tmp_path, table, word):
    table.set(2, "direction", word)
    path = table.write(tmp_path / "direction.csv")
    refused(path, table.line_of_row(2), "direction")


def test_duplicated_row(tmp_path, table):
    table.rows.insert(4, list(table.rows[3]))
    path = table.write(tmp_path / "dup.csv")
    err = refused(path, table.line_of_row(4), "time_s", "duplicated")
    assert f"line {table.line_of_row(3)}" in str(err)


def test_duplicated_row_far_apart(tmp_path, table):
    table.rows.append(list(table.rows[0]))
    path = table.write(tmp_path / "dup2.csv")
    err = refused(path, table.line_of_row(len(table.rows) - 1), "time_s", "duplicated")
    assert f"line {table.line_of_row(0)}" in str(err)


# -- the reader's own rules ------------------------------------------------------------


@pytest.mark.parametrize("change", ["fewer", "more"])
def test_wrong_field_count(tmp_path, table, change):
    if change == "fewer":
        table.rows[6] = table.rows[6][:-1]
    else:
        table.rows[6] = table.rows[6] + ["surplus"]
    path = table.write(tmp_path / "fields.csv")
    # a short row names the first column left without a field; a long row names none
    column = table.header[len(table.rows[6])] if change == "fewer" else None
    refused(path, table.line_of_row(6), column, "fields", str(len(table.header)))


@pytest.mark.parametrize("column", ["sd_x", "sd_y", "sd_z"])
def test_negative_standard_deviation(tmp_path, table, column):
    table.set(3, column, "-1e-5")
    path = table.write(tmp_path / "sd.csv")
    refused(path, table.line_of_row(3), column, "negative")


@pytest.mark.parametrize("value", ["0", "-3"])
def test_n_samples_below_one(tmp_path, table, value):
    table.set(8, "n_samples", value)
    path = table.write(tmp_path / "n.csv")
    refused(path, table.line_of_row(8), "n_samples", "at least 1")


@pytest.mark.parametrize("column, value", [("n_samples", "3000.5"), ("cycle", "one")])
def test_non_integer_counts(tmp_path, table, column, value):
    table.set(1, column, value)
    path = table.write(tmp_path / "int.csv")
    refused(path, table.line_of_row(1), column, "not an integer")


def test_negative_cycle(tmp_path, table):
    table.set(1, "cycle", "-1")
    path = table.write(tmp_path / "cycle.csv")
    refused(path, table.line_of_row(1), "cycle")


@pytest.mark.parametrize("value", ["0", "-30"])
def test_non_positive_averaging_time(tmp_path, table, value):
    table.set(10, "tau_s", value)
    path = table.write(tmp_path / "tau.csv")
    refused(path, table.line_of_row(10), "tau_s", "positive")


@pytest.mark.parametrize("value", ["9.8 m/s2", "nan", "-9.81", "0"])
def test_bad_numeric_metadata(tmp_path, table, value):
    k = next(i for i, c in enumerate(table.comments) if c.startswith("# local_g_m_s2"))
    table.comments[k] = f"# local_g_m_s2 = {value}"
    path = table.write(tmp_path / "meta.csv")
    # a metadata line has no column; the message names the key instead
    refused(path, k + 1, None, "local_g_m_s2", repr(value))


def test_empty_file(tmp_path):
    path = tmp_path / "empty.csv"
    path.write_text("", encoding="utf-8")
    refused(str(path), 1, None, "no header")


def test_comments_only(tmp_path):
    path = tmp_path / "comments.csv"
    path.write_text("# bench = B1\n# operator = A\n", encoding="utf-8")
    refused(str(path), 2, None, "no header")


def test_no_data_rows(tmp_path, table):
    table.rows = []
    path = table.write(tmp_path / "header_only.csv")
    refused(path, table.header_line, None, "no data rows")


def test_sd_without_n_samples(tmp_path, table):
    table.drop_column("n_samples")
    path = table.write(tmp_path / "sd_only.csv")
    refused(path, table.header_line, "n_samples", "together")


def test_n_samples_without_sd(tmp_path, table):
    for c in ("sd_x", "sd_y", "sd_z"):
        table.drop_column(c)
    path = table.write(tmp_path / "n_only.csv")
    refused(path, table.header_line, "sd_x", "together")


def test_incomplete_sd_group(tmp_path, table):
    table.drop_column("sd_y")
    path = table.write(tmp_path / "sd_group.csv")
    refused(path, table.header_line, "sd_y", "together")


def test_column_twice_in_header(tmp_path, table):
    table.header[table.header.index("state")] = "w_x"
    path = table.write(tmp_path / "twice.csv")
    refused(path, table.header_line, "w_x", "twice")


def test_empty_required_field(tmp_path, table):
    table.set(11, "unit", "")
    path = table.write(tmp_path / "emptyunit.csv")
    refused(path, table.line_of_row(11), "unit", "empty")


def test_comment_after_header(tmp_path, table):
    table.rows.insert(2, ["# operator went for coffee"])
    path = table.write(tmp_path / "latecomment.csv")
    refused(path, table.line_of_row(2), table.header[1], "1 fields")  # a row of one field


def test_not_utf8(tmp_path, table):
    text = table.text().encode("utf-8")
    lines = text.split(b"\n")
    lines[table.line_of_row(2) - 1] = lines[table.line_of_row(2) - 1].replace(b"SN-SIM", b"SN-\xe9SIM")
    path = tmp_path / "latin1.csv"
    path.write_bytes(b"\n".join(lines))
    refused(str(path), table.line_of_row(2), None, "UTF-8")


def test_line_numbers_count_blank_lines(tmp_path, table):
    """Blank lines carry no data but are counted in line numbers."""
    text = table.text().splitlines()
    h = table.header_line  # 1-based: index h is the first data row
    text[h:h] = ["", ""]
    bad = h + 2 + 4  # 0-based index of data row 4 after the two blank lines
    fields = next(csv.reader([text[bad]]))
    fields[table.header.index("w_x")] = "oops"
    buf = io.StringIO()
    csv.writer(buf, lineterminator="").writerow(fields)
    text[bad] = buf.getvalue()
    path = tmp_path / "blank.csv"
    path.write_text("\n".join(text) + "\n", encoding="utf-8")
    refused(str(path), bad + 1, "w_x")


def test_blank_lines_and_crlf_are_accepted(tmp_path, table, campaign):
    text = table.text().replace("\n", "\r\n")
    path = tmp_path / "crlf.csv"
    path.write_bytes(text.encode("utf-8") + b"\r\n\r\n")
    c = read_bench_csv(path)
    np.testing.assert_array_equal(c.w, campaign.w)


def test_utf8_byte_order_mark_is_accepted(tmp_path, table, campaign):
    path = tmp_path / "bom.csv"
    path.write_bytes(b"\xef\xbb\xbf" + table.text().encode("utf-8"))
    c = read_bench_csv(path)
    assert c.metadata == campaign.metadata
    np.testing.assert_array_equal(c.w, campaign.w)


def test_empty_field_in_unknown_column_is_kept(tmp_path, table):
    table.header.append("remark")
    for i, row in enumerate(table.rows):
        row.append("door opened" if i == 3 else "")
    path = table.write(tmp_path / "remark.csv")
    c = read_bench_csv(path)
    assert c.extra["remark"][3] == "door opened" and c.extra["remark"][0] == ""


# -- round trips -----------------------------------------------------------------------


FIELDS = ("unit", "setpoint_C", "direction", "time_s", "position", "axis1_deg", "axis2_deg", "tau_s",
          "w", "t", "cycle", "state", "sd", "n_samples")


def assert_same_campaign(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape, name
        np.testing.assert_array_equal(x, y, err_msg=name)
    assert a.metadata == b.metadata
    assert set(a.extra) == set(b.extra)
    for k in a.extra:
        np.testing.assert_array_equal(a.extra[k], b.extra[k], err_msg=k)


def test_round_trip_simulate_write_read(tmp_path, campaign):
    path = tmp_path / "campaign.csv"
    write_bench_csv(campaign, path)
    back = read_bench_csv(path)
    assert_same_campaign(campaign, back)
    assert back.source == str(path)
    assert back.n_samples.dtype.kind == "i" and back.cycle.dtype.kind == "i"
    # lines: header after the metadata comments, one data row per line
    first = len(campaign.metadata) + 2
    np.testing.assert_array_equal(back.lines, np.arange(first, first + campaign.n_visits))
    assert not list(tmp_path.glob("*.tmp")), "the atomic write left its temporary file behind"


def test_round_trip_with_all_effects_and_heavy_tails(tmp_path):
    from triadcal.api import simulate
    from triadcal.models.effects import VOCABULARY

    _, c = simulate(tmp_path / "all.csv", effects=VOCABULARY,
                    schedule=Schedule(setpoints_C=(20.0, -5.0), soak_s=300.0), seed=11)
    assert_same_campaign(c, read_bench_csv(tmp_path / "all.csv"))


def test_written_text_is_a_fixed_point(tmp_path, campaign):
    text = format_bench_csv(campaign)
    path = tmp_path / "a.csv"
    path.write_text(text, encoding="utf-8")
    assert format_bench_csv(read_bench_csv(path)) == text


def test_unknown_columns_are_kept_and_written_back(tmp_path, table, campaign):
    table.header[3:3] = ["chamber_C"]
    table.header.append("operator note")
    for i, row in enumerate(table.rows):
        row[3:3] = [f"{20 + 0.1 * i:.1f}"]
        row.append(f"visit {i}, ok")  # a comma inside a quoted field
    path = table.write(tmp_path / "extra.csv")
    c = read_bench_csv(path)
    assert list(c.extra) == ["chamber_C", "operator note"]
    assert c.extra["chamber_C"][0] == "20.0" and c.extra["operator note"][5] == "visit 5, ok"
    np.testing.assert_array_equal(c.w, campaign.w)

    out = tmp_path / "extra_back.csv"
    write_bench_csv(c, out)
    again = read_bench_csv(out)
    assert_same_campaign(c, again)
    header = next(l for l in out.read_text(encoding="utf-8").splitlines() if not l.startswith("#"))
    assert header.endswith("chamber_C,operator note")


def test_extra_columns_survive_select(tmp_path, table):
    table.header.append("note")
    for i, row in enumerate(table.rows):
        row.append(f"n{i}")
    c = read_bench_csv(table.write(tmp_path / "note.csv"))
    sub = c.select(np.arange(c.n_visits) % 2 == 1)
    assert list(sub.extra["note"]) == [f"n{i}" for i in range(1, c.n_visits, 2)]


def test_column_order_is_free(tmp_path, table, campaign):
    rng = np.random.default_rng(5)
    order = rng.permutation(len(table.header))
    assert list(order) != list(range(len(order)))
    table.header = [table.header[j] for j in order]
    table.rows = [[row[j] for j in order] for row in table.rows]
    c = read_bench_csv(table.write(tmp_path / "shuffled.csv"))
    assert_same_campaign(campaign, c)


def test_optional_columns_take_their_defaults(tmp_path, table):
    for col in ("cycle", "state", "sd_x", "sd_y", "sd_z", "n_samples"):
        table.drop_column(col)
    c = read_bench_csv(table.write(tmp_path / "minimal.csv"))
    assert (c.cycle == 0).all() and (c.state == "initial").all()
    assert c.sd is None and c.n_samples is None and c.output_sigma() is None


def test_metadata_lines_and_plain_comments(tmp_path, table):
    table.comments = ["# a free comment without a key", "#operator=J. Doe", "",
                      "# local_g_m_s2 = 9.8155", "# note = a = b"]
    c = read_bench_csv(table.write(tmp_path / "meta.csv"))
    assert c.metadata == {"operator": "J. Doe", "local_g_m_s2": "9.8155", "note": "a = b"}
    assert c.local_g_m_s2 == 9.8155
    assert c.gravity_g == pytest.approx(9.8155 / 9.80665, rel=1e-15)


def test_a_file_the_reader_accepts_has_finite_temperature_rates(tmp_path, table):
    table.set(5, "time_s", table.rows[4][table.header.index("time_s")])
    path = table.write(tmp_path / "sametime.csv")
    try:
        c = read_bench_csv(path)
    except BenchCSVError as err:  # refusing the file is a valid fix too
        assert err.line == table.line_of_row(5) and err.column == "time_s"
        return
    with np.errstate(divide="ignore", invalid="ignore"):
        rate = c.temperature_rate()
    assert np.isfinite(rate).all()


def test_unit_starting_with_hash_round_trips(tmp_path):
    c = simulate_campaign(preset_truth(unit="#0042"), schedule=Schedule(setpoints_C=(20.0,), soak_s=60.0), seed=0)
    write_bench_csv(c, tmp_path / "hash.csv")
    assert_same_campaign(c, read_bench_csv(tmp_path / "hash.csv"))
