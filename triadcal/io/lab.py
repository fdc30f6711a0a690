"""The lab file (TOML): the laboratory, its bench and chamber figures and the certificate's
statements; validated field by field (docs/certificate.md, "The lab file").
"""

from __future__ import annotations

from ..errors import InputError

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional


# =========================================================================================
# the lab's configuration
# =========================================================================================
@dataclass
class LabConfig:
    """The laboratory's fields for the certificate, read from a TOML file (:func:`load_lab`).

    Numbers the budget uses: ``sigma_position_arcsec`` and ``sigma_wobble_arcsec`` (the
    bench's positioning error and wobble, sigma_1 and sigma_2 of eq. 4) and
    ``temperature_uncertainty_C`` (Delta T of eq. 7).
    """

    name: str = "Laboratory not stated (no lab file given)"
    address: str = ""
    accreditation: str = ""
    certificate_prefix: str = "TC"
    place: str = ""
    signatory_name: str = ""
    signatory_title: str = ""
    customer_name: str = ""
    customer_address: str = ""
    item_description: str = "accelerometer triad"
    calibration_date: str = ""
    bench: str = ""
    sigma_position_arcsec: Optional[float] = None
    sigma_wobble_arcsec: Optional[float] = None
    chamber: str = ""
    fixture: str = ""
    thermometers: str = ""
    temperature_uncertainty_C: Optional[float] = None
    traceability: str = ""
    source: Optional[str] = None
    #: systematic errors of the bench and the fixture (standard uncertainties, arcsec)
    axes_nonorthogonality_u_arcsec: Optional[float] = None
    encoder_zero_u_arcsec: Optional[float] = None
    mounting_u_arcsec: Optional[float] = None
    #: local gravity measured by the lab (m/s^2) and its standard uncertainty (ppm)
    local_g_m_s2: Optional[float] = None
    local_g_u_ppm: Optional[float] = None
    #: an analog unit's voltmeter (one per axis or a scanner): gain (ppm of reading) and offset (V)
    voltmeter: str = ""
    voltmeter_gain_u_ppm: Optional[float] = None
    voltmeter_offset_u_V: Optional[float] = None
    #: the unit's own stability: u of its bias drift rate during the campaign (ug/h; ``[item]
    #: bias_drift_u_ug_per_h``, from its datasheet or history): a Type B row of every parameter a
    #: drift would move, about the campaign's middle (docs/lab.md, "The unit's bias drift")
    bias_drift_u_ug_per_h: Optional[float] = None
    #: the distribution of each section's systematic terms: {section: "normal" | "rectangular" |
    #: "arcsine"}; the stated value is always the standard uncertainty (docs/lab.md)
    distributions: dict = field(default_factory=dict)
    #: equipment whose systematic errors are the same in two calibrations compared with this
    #: lab file (``[compare] shared_equipment``; default none: independent, the conservative case)
    shared_equipment: tuple = ()
    #: the equipment's own calibration: {section: {"instrument", "certificate", "due"}}
    equipment: dict = field(default_factory=dict)
    #: the calibration history database (SQLite, ``[history] path``; relative to the lab file's
    #: folder), used by ``triadcal history`` and ``triadcal batch --history`` (docs/fleet.md)
    history_path: str = ""

    def expired(self, on: str) -> list:
        """Equipment whose calibration certificate was due before the date ``on`` (ISO
        YYYY-MM-DD), as sentences."""
        out = []
        for section, e in self.equipment.items():
            due = e.get("due")
            if due and on and str(due) < str(on):
                out.append(f"the {section} ({e.get('instrument') or 'instrument not named'}, certificate "
                           f"{e.get('certificate') or 'not named'}) was due for calibration on {due}, before {on}")
        return out


#: TOML section -> key -> (field, type)
LAB_SCHEMA = {
    "lab": {"name": ("name", str), "address": ("address", str), "accreditation": ("accreditation", str),
            "certificate_prefix": ("certificate_prefix", str), "place": ("place", str)},
    "signatory": {"name": ("signatory_name", str), "title": ("signatory_title", str)},
    "customer": {"name": ("customer_name", str), "address": ("customer_address", str)},
    "item": {"description": ("item_description", str), "calibration_date": ("calibration_date", str),
             "bias_drift_u_ug_per_h": ("bias_drift_u_ug_per_h", float)},
    "bench": {"name": ("bench", str), "sigma_position_arcsec": ("sigma_position_arcsec", float),
              "sigma_wobble_arcsec": ("sigma_wobble_arcsec", float),
              "positioning_sd_arcsec": ("sigma_position_arcsec", float),
              "wobble_sd_arcsec": ("sigma_wobble_arcsec", float),
              "axes_nonorthogonality_u_arcsec": ("axes_nonorthogonality_u_arcsec", float),
              "encoder_zero_u_arcsec": ("encoder_zero_u_arcsec", float)},
    "fixture": {"name": ("fixture", str), "mounting_u_arcsec": ("mounting_u_arcsec", float)},
    "chamber": {"name": ("chamber", str), "temperature_uncertainty_C": ("temperature_uncertainty_C", float)},
    "thermometers": {"name": ("thermometers", str), "u_C": ("temperature_uncertainty_C", float)},
    "gravity": {"local_g_m_s2": ("local_g_m_s2", float), "u_ppm": ("local_g_u_ppm", float)},
    "voltmeter": {"name": ("voltmeter", str), "gain_u_ppm": ("voltmeter_gain_u_ppm", float),
                  "offset_u_V": ("voltmeter_offset_u_V", float)},
    "traceability": {"statement": ("traceability", str)},
    "compare": {"shared_equipment": ("shared_equipment", list)},
    "history": {"path": ("history_path", str)},
}

#: keys any equipment section may carry: the instrument, its calibration certificate, its due date
EQUIPMENT_KEYS = ("instrument", "certificate", "due")
EQUIPMENT_SECTIONS = ("bench", "fixture", "chamber", "thermometers", "gravity", "voltmeter")
#: sections whose systematic terms may state their ``distribution`` (the values are standard
#: uncertainties whatever the distribution: a rectangular +-a is stated as a/sqrt(3))
DISTRIBUTION_SECTIONS = ("bench", "fixture", "thermometers", "gravity", "voltmeter", "item")
#: equipment whose systematic errors two calibrations on one bench may share (``[compare]
#: shared_equipment``): the lab's, not the unit's own drift, which is a new error in every campaign
SHAREABLE_SECTIONS = ("bench", "fixture", "thermometers", "gravity", "voltmeter")
DISTRIBUTIONS = ("normal", "rectangular", "arcsine")


EXAMPLE_LAB_TOML = """\
[lab]
name = "Inertial Sensors Calibration Laboratory"
address = "1 Metrology Road, Springfield"
accreditation = "Accredited to ISO/IEC 17025:2017, certificate No. 0000.01"
certificate_prefix = "ISCL"
place = "Springfield"

[signatory]
name = "A. N. Engineer"
title = "Head of the inertial laboratory"

[customer]
name = "Example Avionics Ltd"
address = "2 Customer Street, Springfield"

[item]
description = "accelerometer triad (IMU accelerometer block)"
# the date the data were taken; needed only when the data carry none (capture writes it)
# calibration_date = "YYYY-MM-DD"
# bias_drift_u_ug_per_h = 0.1   # u of the unit's bias drift rate during the campaign (its stability)
# distribution = "rectangular"  # e.g. a datasheet's bound b stated as u = b / sqrt(3)

[bench]
name = "two-axis rate-and-position table, thermal chamber"
instrument = "two-axis table, serial 0001"
certificate = "ANG-2026-0417"
due = 2027-06-30
sigma_position_arcsec = 5.0     # random positioning error of each axis per visit, sigma_1 of eq. 4
sigma_wobble_arcsec = 2.0       # random wobble of axis 1 per visit, sigma_2 of eq. 4
axes_nonorthogonality_u_arcsec = 2.0   # u of the angle between the two bench axes (systematic)
encoder_zero_u_arcsec = 2.0     # u of each axis's zero (systematic)

[fixture]
name = "cube fixture"
mounting_u_arcsec = 3.0         # u of the unit's rotation in its fixture (systematic)

[gravity]
# the site's measured local gravity and its u (ppm), required with it: K takes g one to one, and a
# certificate needs its row in K's budget. 9.80665 is the example campaign's (simulated at standard
# gravity): put your site's value (data that state another are refused, naming both)
local_g_m_s2 = 9.80665
u_ppm = 10

[chamber]
name = "thermal chamber -60..+100 °C"

# [voltmeter]                   # an analog unit's outputs read by a DMM (one per axis or a scanner)
# instrument = "DMM 34465A, serial MY0000"
# gain_u_ppm = 15               # u of the meter's gain, ppm of reading
# offset_u_V = 2e-6             # u of the meter's offset, V

[thermometers]
name = "Pt100 sensor on each accelerometer"
certificate = "TMP-2026-112"
due = 2027-03-31
u_C = 0.2                       # Delta T of eq. 7

[traceability]
statement = "Angles traceable to the national standard of plane angle through the bench's calibration certificate; local gravity from the national gravimetric survey."
"""


def load_lab(path) -> LabConfig:
    """Read a lab configuration TOML (sections ``[lab] [signatory] [customer] [item] [bench]
    [fixture] [chamber] [thermometers] [gravity] [traceability]``, see ``EXAMPLE_LAB_TOML`` and
    docs/lab.md); the equipment sections may name their ``instrument``, ``certificate`` and
    ``due`` date. Unknown sections or keys and values of the wrong type are refused with the
    file, section and key named."""
    path = Path(path)
    from .atomic import read_toml

    data = read_toml(path, "a lab file")
    lab = LabConfig(source=str(path))
    given: dict = {}                       # attribute -> "[section] key" that set it (synonyms clash)
    for section, table in data.items():
        if section not in LAB_SCHEMA:
            raise InputError(f"{path}: unknown section [{section}]; known: {', '.join(LAB_SCHEMA)}")
        if not isinstance(table, dict):
            raise InputError(f"{path}: {section} must be a [section] table")
        for key, value in table.items():
            if section in DISTRIBUTION_SECTIONS and key == "distribution":
                if value not in DISTRIBUTIONS:
                    raise InputError(f"{path}: [{section}] distribution = {value!r}; choose one of "
                                     f"{', '.join(DISTRIBUTIONS)}")
                lab.distributions[section] = value
                continue
            if section in EQUIPMENT_SECTIONS and key in EQUIPMENT_KEYS:
                if key == "due":
                    value = _iso_date(value, path, section)
                lab.equipment.setdefault(section, {})[key] = str(value)
                continue
            if key not in LAB_SCHEMA[section]:
                raise InputError(f"{path}: unknown key {key!r} in [{section}]; known: "
                                 f"{', '.join(LAB_SCHEMA[section])}")
            name, typ = LAB_SCHEMA[section][key]
            if typ is float:
                if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) \
                        or value < 0:
                    raise InputError(f"{path}: [{section}] {key} must be a non-negative number, got {value!r}")
                value = float(value)
            elif typ is list:
                if not isinstance(value, list) or not all(v in SHAREABLE_SECTIONS for v in value):
                    raise InputError(f"{path}: [{section}] {key} must be a list of equipment sections from "
                                     f"{', '.join(SHAREABLE_SECTIONS)}, got {value!r}")
                value = tuple(value)
            elif not isinstance(value, str):
                value = str(value)  # TOML dates etc. are written as they read
            if name in given:
                raise InputError(f"{path}: [{section}] {key} and {given[name]} state the same quantity; give one "
                                 "(the file's order decided it silently before)")
            given[name] = f"[{section}] {key}"
            setattr(lab, name, value)
    for name, limit, why in LAB_U_LIMITS:
        v = getattr(lab, name, None)
        if v is not None and v > limit:
            raise InputError(f"{path}: {given[name]} = {v:g} is above {limit:g}: {why}")
    if lab.local_g_u_ppm is not None and lab.local_g_m_s2 is None:
        raise InputError(f"{path}: [gravity] u_ppm = {lab.local_g_u_ppm:g} without local_g_m_s2: a u is that of a "
                         "measured local gravity; without one the fit uses standard gravity, which differs from a "
                         "site's g by up to 2 600 ppm; state the measured local_g_m_s2 (or leave out u_ppm)")
    if lab.local_g_m_s2 is not None and not 9.76 <= lab.local_g_m_s2 <= 9.84:
        raise InputError(f"{path}: [gravity] local_g_m_s2 = {lab.local_g_m_s2:g} is not a gravity on the Earth's "
                         "surface (9.76 to 9.84 m/s2)")
    if lab.local_g_m_s2 is not None and lab.local_g_u_ppm is None:
        # the reverse of the u_ppm check: a g without its u was taken as exact, the certificate said
        # "measured, lab file" with no local-gravity row in K's budget (K's U 8.4 ppm instead of 21.7 at
        # u_ppm = 10; an outside probe who uncommented only the example's first line)
        raise InputError(f"{path}: [gravity] local_g_m_s2 = {lab.local_g_m_s2:g} without u_ppm: a measured gravity "
                         "has an uncertainty, and K takes it one to one; state u_ppm (ppm; a gravimeter survey "
                         "gives < 0.1, a gravity model 10 to 50)")
    return lab


#: upper limits of the lab's uncertainties: (attribute, limit, why); beyond them the linear
#: propagation of eq. 4-7 and of the fit's Type B budget does not hold (an outside probe: u_ppm = 1e6
#: and mounting_u_arcsec = 1e6 were propagated linearly, a certificate issued with K = 1.0 +- 2.0 g/V)
LAB_U_LIMITS = tuple(
    [(n, 3600.0, "an angle's u above 1 degree (the answer gates' bound) is no small error; the linear "
                 "propagation of eq. 4-7 and of the fit's budget does not hold there")
     for n in ("axes_nonorthogonality_u_arcsec", "encoder_zero_u_arcsec", "mounting_u_arcsec",
               "sigma_position_arcsec", "sigma_wobble_arcsec")]
    + [("local_g_u_ppm", 3000.0, "the local gravity's u in ppm: standard gravity itself is within 2 600 ppm of "
                                 "every site's g"),
       ("voltmeter_gain_u_ppm", 1e5, "a voltmeter's gain u above 10 % is no calibrated meter"),
       # 2.0 (meant as 2 uV) gave a certificate with S = 0.0008 +- 4 g (an outside probe)
       ("voltmeter_offset_u_V", 0.01, "a voltmeter's offset u above 10 mV is no calibrated meter on its volt "
                                      "ranges (a 6.5-digit meter's is a few uV): a unit slip? the field is in V"),
       ("temperature_uncertainty_C", 50.0, "a thermometer's u above 50 degC is no measured temperature"),
       ("bias_drift_u_ug_per_h", 1e4, "a bias drifting by 10 mg per hour is no unit to calibrate (the budget "
                                      "would hold nothing but the drift)")])


def _iso_date(value, path, section) -> str:
    """A due date as YYYY-MM-DD (a TOML date or a string of that form), else refused."""
    import datetime as _dt

    if isinstance(value, _dt.datetime):
        return value.date().isoformat()
    if isinstance(value, _dt.date):
        return value.isoformat()
    try:
        return _dt.date.fromisoformat(str(value)).isoformat()
    except ValueError:
        raise InputError(f"{path}: [{section}] due = {value!r} is not a date (YYYY-MM-DD)") from None


def bench_errors_of(lab: "LabConfig"):
    """The lab's random bench errors for the fit (:class:`triadcal.estimation.joint.BenchErrors`),
    or None when the lab file states neither; a missing one of the two is taken as 0 and said."""
    if lab.sigma_position_arcsec is None and lab.sigma_wobble_arcsec is None:
        return None
    from ..estimation.joint import BenchErrors

    return BenchErrors(lab.sigma_position_arcsec or 0.0, lab.sigma_wobble_arcsec or 0.0,
                       f"lab file {lab.source}" if lab.source else "lab file")


def with_lab_gravity(campaign, lab: Optional["LabConfig"]):
    """The campaign with the lab's measured local gravity when the data state none (their
    ``# local_g_m_s2`` metadata absent): the lab file's ``[gravity] local_g_m_s2`` is then the
    g of the fit (K is in g per output unit, so a wrong g goes one to one into K). Data and lab
    file that state different values (beyond 3 u of the lab's, or 1 ppm without a u) are
    refused naming both; equal values, or no lab value, leave the campaign as it is."""
    if lab is None or lab.local_g_m_s2 is None:
        return campaign
    stated = campaign.metadata.get("local_g_m_s2")
    if stated is None:
        from dataclasses import replace

        meta = dict(campaign.metadata)
        meta["local_g_m_s2"] = repr(lab.local_g_m_s2)
        meta["local_g_source"] = f"lab file {lab.source or ''}".strip()
        return replace(campaign, metadata=meta)
    try:
        g = float(stated)
    except ValueError:
        raise InputError(f"{campaign.source or 'campaign'}: local_g_m_s2 = {stated!r} is not a number") from None
    tol = 3e-6 * (lab.local_g_u_ppm if lab.local_g_u_ppm else 1.0 / 3.0) * lab.local_g_m_s2
    if abs(g - lab.local_g_m_s2) > tol:
        raise InputError(f"{campaign.source or 'campaign'} states local_g_m_s2 = {g:.7g} and the lab file "
                         f"{lab.source or ''} [gravity] local_g_m_s2 = {lab.local_g_m_s2:.7g} "
                         f"({(g / lab.local_g_m_s2 - 1) * 1e6:+.1f} ppm): one of them is wrong (K takes g one to one)")
    return campaign
