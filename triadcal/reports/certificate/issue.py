"""``certificate``: check the result, build the certificate (or the refusal report) and write
its HTML and PDF.
"""

from __future__ import annotations

from ...errors import InputError

from pathlib import Path
from typing import Optional

from ...estimation.result_checks import check_result_for_use
from ...estimation.result import CalibrationResult
from ...io.atomic import read_json
from ...io.formats import require_format
from ...io.atomic import atomic_write_bytes, atomic_write_text
from .content import Certificate, build_certificate
from .html import render_html
from ...io.lab import LabConfig, load_lab
from .pdf import render_pdf


# =========================================================================================
# the library function behind `triadcal certificate`
# =========================================================================================
def certificate(result, *, posterior=None, lab=None, data=None, diagnosis=None, html=None, pdf=None,
                plots_dir=None, number: Optional[str] = None, issue_date: Optional[str] = None,
                allow_expired_equipment: bool = False) -> Certificate:
    """Issue a certificate (``triadcal certificate``) or, when a diagnostic failed, a refusal report.

    ``result``: a results-json path or a CalibrationResult; ``posterior``: netCDF path or
    InferenceData; ``lab``: TOML path or LabConfig; ``data``: bench CSV path or Campaign;
    ``diagnosis``: a diagnosis JSON path or dict. ``allow_expired_equipment``: issue even when
    the lab file's equipment was due for calibration before the calibration date (printed). Writes ``html``, ``pdf`` and the plots as
    PNG in ``plots_dir`` when given; returns the :class:`Certificate` (``issued`` says which).
    """
    result_path = None
    if not isinstance(result, CalibrationResult):
        result_path = result
        result = CalibrationResult.load(result)
    # a result that is not a calibration at all (no parameters, values or u not finite, K <= 0
    # or outside its unit's band, an angle beyond the gate, no reference temperature) is
    # refused outright, one line, before any file is written; a result whose estimator said
    # "not ok" gets the refusal report below
    check_result_for_use(result, str(result_path or f"result of {result.unit}"), need_ok=False, content=False)
    if lab is not None and not isinstance(lab, LabConfig):
        lab = load_lab(lab)
    if posterior is not None:
        what = str(posterior) if not hasattr(posterior, "posterior") else "the posterior"
        if not hasattr(posterior, "posterior"):
            from ...io.netcdf import read_inference_data

            posterior = read_inference_data(posterior)
        # the posterior must be the result's (compare's check, reused): a posterior of another unit gave
        # a certificate with that unit's R-hat, ESS and plots (an outside probe)
        from ...judgement.compare.correlation import check_posterior_identity, check_posterior_moments, posterior_draws

        draws = posterior_draws(posterior)
        check_posterior_identity(posterior, draws, result, what)
        # and its draws must be the result's: an edited file (Ca_xy's draws +500 arcsec, its stored verdict
        # kept) and another campaign's posterior were certified (an outside probe)
        check_posterior_moments(draws, result, what)
    if data is not None and not hasattr(data, "n_visits"):
        from ...io.bench_csv import read_bench_csv

        data = read_bench_csv(data)
    if data is not None:
        from .against_data import fitted_visits

        data = fitted_visits(data, result)
    if data is not None and data.units != [result.unit]:
        raise InputError(f"the campaign data is of unit(s) {data.units}, the result of {result.unit!r}")
    if diagnosis is not None and not isinstance(diagnosis, dict):
        source = str(diagnosis)
        diagnosis = read_json(diagnosis)
        from ...judgement.diagnose import FORMAT, VERSION

        require_format(diagnosis, FORMAT, VERSION, source, "a diagnosis", "diagnosis")
        gap = diagnosis.get("gap")
        if not isinstance(gap, dict) or not isinstance(gap.get("significant"), bool):
            raise InputError(f"{source}: gap.significant is missing or not true/false")
        if not isinstance(diagnosis.get("verdict"), dict):
            raise InputError(f"{source}: verdict is missing or not an object")
    cert = build_certificate(result, lab=lab, campaign=data, idata=posterior, diagnosis=diagnosis, number=number,
                             allow_expired_equipment=allow_expired_equipment,
                             issue_date=issue_date, result_path=result_path)
    if html is not None:
        atomic_write_text(html, render_html(cert))
    if pdf is not None:
        render_pdf(cert, pdf)
    if plots_dir is not None and cert.plots:
        Path(plots_dir).mkdir(parents=True, exist_ok=True)
        for p in cert.plots:
            atomic_write_bytes(Path(plots_dir) / f"{p.name}.png", p.png)
    return cert
