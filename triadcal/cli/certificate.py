"""``triadcal certificate``: a calibration certificate (HTML, PDF) from a result, or a refusal report."""

from __future__ import annotations

from ..errors import InputError

import sys

from ._common import add_output_options, output


def register(sub) -> None:
    p = sub.add_parser(
        "certificate", help="write the calibration certificate of a result (HTML and/or PDF)",
        description="Write a calibration certificate (ISO/IEC 17025 7.8) from a results-json file: "
                    "identification, method, conditions, every parameter with its expanded uncertainty "
                    "(k = 2), the thermal model, the inverse matrix, an uncertainty budget (eq. 4-7) and "
                    "plots. When a diagnostic failed (status not ok, undetermined terms, a significant "
                    "model-data gap, a posterior that did not mix) no certificate is issued: the same "
                    "files hold a report that says why, and the command exits with status 3. Given a "
                    "comparison file instead, it writes the drift report.")
    p.add_argument("result", nargs="?", help="calibration result (results-json v1, from `triadcal fit` or `sample`); "
                                              "given a comparison (`triadcal compare --json`), writes its drift report")
    p.add_argument("--posterior", metavar="P.nc", help="posterior draws (arviz netCDF): pair and trace/rank plots, "
                                                       "R-hat and ESS checks")
    p.add_argument("--lab", metavar="LAB.toml", help="the laboratory's fields (see docs/certificate.md; "
                                                    "`--lab-example` prints one)")
    p.add_argument("--data", metavar="DATA.csv", help="the campaign (bench CSV v1): plan, setpoints, residual "
                                                      "and angle-temperature plots, thermal-model residual")
    p.add_argument("--diagnosis", metavar="D.json", help="a diagnosis (triadcal.diagnosis JSON); a significant "
                                                         "gap refuses the certificate")
    p.add_argument("--html", metavar="OUT.html", help="write the self-contained HTML here")
    p.add_argument("--pdf", metavar="OUT.pdf", help="write the PDF here")
    p.add_argument("--plots", metavar="DIR", help="also write the plots as PNG files into DIR")
    p.add_argument("--number", help="certificate number from the lab's register (default: PREFIX-DATE-HASH)")
    p.add_argument("--date", metavar="YYYY-MM-DD", help="date of issue (default: today)")
    p.add_argument("--lab-example", action="store_true", help="print an example lab file and exit")
    p.add_argument("--allow-expired-equipment", action="store_true",
                   help="issue even when equipment of the lab file was due for calibration before the "
                        "calibration date (the expiry is printed on the certificate)")
    add_output_options(p)
    p.set_defaults(func=run)


def _format_of(path) -> str:
    """The document's ``format``; "" when it cannot be read (the result reader then says why)."""
    from ..io.atomic import read_json

    try:
        d = read_json(path)
    except ValueError:
        return ""
    return str(d.get("format", "")) if isinstance(d, dict) else ""


def run(args) -> int:
    from ..reports.certificate import EXAMPLE_LAB_TOML, certificate
    from ..reports.certificate.content import values_temperature

    if args.lab_example:
        print(EXAMPLE_LAB_TOML, end="")            # asked for: printed even with --quiet
        return 0
    say = output(args).say
    if not args.result:
        raise InputError("give a result file (results-json v1)")
    if not (args.html or args.pdf):
        raise InputError("give --html OUT.html and/or --pdf OUT.pdf")
    if args.date:
        import datetime

        try:
            datetime.date.fromisoformat(args.date)
        except ValueError:
            raise InputError(f"--date: expected YYYY-MM-DD, got {args.date!r}") from None
    if _format_of(args.result) == "triadcal.comparison":
        from ..reports.certificate import drift_report

        comp = drift_report(args.result, lab=args.lab, html=args.html, pdf=args.pdf, issue_date=args.date)
        say(f"drift report written to {' and '.join(x for x in (args.html, args.pdf) if x)}: overall verdict "
            f"{comp.get('overall') or 'not given'}, {len(comp.get('parameters', {}))} parameters")
        return 0
    cert = certificate(args.result, posterior=args.posterior, lab=args.lab, data=args.data,
                       diagnosis=args.diagnosis, html=args.html, pdf=args.pdf, plots_dir=args.plots,
                       number=args.number, issue_date=args.date,
                       allow_expired_equipment=args.allow_expired_equipment)
    written = ", ".join(x for x in (args.html, args.pdf) if x)
    if cert.issued:
        say(f"certificate {cert.number} issued for {cert.result.unit}: {written}")
        b = cert.budget
        if cert.parameter_budgets:
            say(f"  {len(cert.rows)} parameters, U (95.45 %) at {values_temperature(cert.result)} from each "
                f"parameter's budget: the {cert.source_of_u} (Type A) and the lab's systematic errors (Type B)")
        else:
            say(f"  {len(cert.rows)} parameters, U (k = 2) at {values_temperature(cert.result)} from the "
                f"{cert.source_of_u} (Type A only)")
        if cert.angle_statement:
            say(f"  {cert.angle_statement} Largest component: {b.components[0].source}.")
        for name, why in cert.skipped_plots.items():
            say(f"  plot {name} not drawn: {why}")
        if args.plots:
            say(f"  plots written to {args.plots.rstrip('/')}/")
        return 0
    print(f"no certificate issued for {cert.result.unit}; the report says why: {written}", file=sys.stderr)
    for reason in cert.reasons:
        print(f"  - {reason}", file=sys.stderr)
    return 3
