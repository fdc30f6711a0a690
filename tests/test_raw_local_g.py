"""fit-raw without a stated local g (docs/raw.md, "Local gravity"): K and S scale with g one to one, and a
recording made at 9.78 m/s^2 fitted with the assumed 9.81 gave K 0.3 % (about 100 u) high with status ok
(an outside probe). The assumption is now said, with what it can cost, and no certificate is issued for
it. The recording is made with numpy (tests/test_raw_diagnosis.py's generator), scaled to 9.78 m/s^2."""

from test_raw_diagnosis import RATE, recording
from triadcal.estimation.raw import fit_raw
from triadcal.io.raw import RawRecording
from triadcal.reports.certificate.refusal import refusal_reasons


def _at(g_m_s2, seed=11):
    rec = recording(seed=seed, noise_mg=0.3)
    # the readings of a unit whose gravity is g_m_s2: |A| = g / 9.80665 (K and S of the generator kept)
    w = rec.acc * (g_m_s2 / 9.80665)
    return RawRecording(w, RATE, "g", ("ax", "ay", "az"), source=rec.source)


def test_an_assumed_local_g_is_said_with_its_cost_and_refused_a_certificate():
    rec = _at(9.78)
    assumed = fit_raw(rec, poses="unknown").result
    stated = fit_raw(rec, poses="unknown", local_g_m_s2=9.78).result
    assert assumed.extra["local_g_stated"] is False and stated.extra["local_g_stated"] is True
    note = next(n for n in assumed.notes if n.startswith("local g not stated"))
    # the cost: max(9.81 - 9.780, 9.832 - 9.81) / 9.81 = 0.31 %, in units of K_x's u
    k = assumed["K_x"]
    assert "up to 0.31 %" in note and f"{0.0030581 * k.value / k.u:.3g} times K_x's u" in note, note
    # what the note warns of: the assumed g puts K off by the g's ratio, far beyond its u
    ratio = assumed["K_x"].value / stated["K_x"].value
    assert abs(ratio - 9.81 / 9.78) < 1e-6 and abs(assumed["K_x"].value - stated["K_x"].value) > 20 * k.u
    assert any(r.startswith("the data state no local gravity (9.81 m/s2 assumed)") and "fit-raw --local-g" in r
               for r in refusal_reasons(assumed))
    assert not any("local g" in r for r in refusal_reasons(stated))
    assert not any(n.startswith("local g not stated") for n in stated.notes)
