"""File names of results (batch's results/UNIT__STATE.json, fit --json-dir): one to one, so two
serials never share a file (before: SN/1 and SN_1 wrote one file, the last fitted won, a warning
said so)."""

from hypothesis import given, settings, strategies as st

from triadcal.fleet.batch import result_path, safe_name

TRICKY = ["SN_1", "SN/1", "SN 1", "SN:1", "A__B", "A", "B__x", "x", ".", "..", ".hidden", "_hidden", "",
          "ünit", "unit", "SN-0003", "a/../b", "a_.._b"]


def test_tricky_serials_and_states_give_distinct_files():
    names = {result_path("out", u, s).name for u in TRICKY for s in ("initial", "after shock", "after_shock")}
    assert len(names) == len(TRICKY) * 3
    assert safe_name("SN-0003") == "SN-0003" and result_path("o", "SN-0003", "initial").name == "SN-0003__initial.json"
    for n in names:
        assert "/" not in n and not n.startswith(".")


@settings(max_examples=300, deadline=None, derandomize=True)
@given(st.text(max_size=12), st.text(max_size=12), st.text(max_size=12), st.text(max_size=12))
def test_two_pairs_share_a_file_only_when_equal(u1, s1, u2, s2):
    same = result_path("o", u1, s1) == result_path("o", u2, s2)
    assert same == ((u1, s1) == (u2, s2))
