"""``triadcal batch``: every (unit, state) of many bench CSV files fitted with the joint
estimator on a dask.distributed cluster, one results JSON per unit and state, resumable.

The work is cut into tasks of whole files (a task reads its file once and fits its pairs one
after the other); when there are fewer files than twice the workers, each file is cut into
parts (part i of k fits the pairs i, i + k, ...), so one multi-unit file still keeps every
worker busy. A task writes each result as soon as it is fitted (atomically,
:mod:`triadcal.io.atomic`), so a batch killed at any moment loses nothing already written, and
skips a pair whose result file exists and records the SHA-256 of the same input file
(``batch.input_sha256`` in the result) and made with the same settings (``batch.settings_sha256``:
the fit options and the lab file, or a manifest entry's reading options). The numbers are those of :func:`triadcal.api.fit` on
the same selection: the task calls it, with one BLAS thread (docs/fleet.md).
"""

from __future__ import annotations

import hashlib
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Optional, Sequence

from ..errors import InputError
# the inputs and the names of the results (importable from here as before)
from .inputs import (MAX_NAME_CHARS, expand_inputs, find_inputs, result_path, safe_name,  # noqa: F401
                     same_name_key, sha256_of)

#: one BLAS/OpenMP thread per worker: the matrices are small (triadcal/cli/__init__.py)
WORKER_ENV = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


# -- the options of a fit and the task ---------------------------------------------------------

@dataclass(frozen=True)
class FitOptions:
    """What every fit of the batch is given (the defaults of ``triadcal fit --method joint``)."""

    effects: Optional[tuple] = None           # None: DEFAULT_EFFECTS
    reference_temperature_C: float = 20.0
    loss: str = "l2"
    strict: bool = False
    angle_bound_arcsec: float = 3600.0

    def kwargs(self) -> dict:
        from ..models.effects import DEFAULT_EFFECTS

        return dict(method="joint", effects=list(self.effects) if self.effects is not None else DEFAULT_EFFECTS,
                    reference_temperature_C=self.reference_temperature_C, loss=self.loss, strict=self.strict,
                    angle_bound_arcsec=self.angle_bound_arcsec)


def settings_sha256(*settings) -> str:
    """SHA-256 of what a fit was given besides its input (the fit options, the lab file, a manifest
    entry's reading options), in a canonical JSON: a result is reused only when it was made with
    the same settings. An outside probe's rerun with --effects, --angle-bound-arcsec or --lab reused
    every result of the first run and reported them ok (one lacked the lab's Type B, another the
    angle gate's refusal)."""
    import dataclasses
    import json

    def plain(x):
        if dataclasses.is_dataclass(x) and not isinstance(x, type):
            return dataclasses.asdict(x)
        return x

    text = json.dumps([plain(s) for s in settings], sort_keys=True, default=str)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def _existing(path: Path, sha: str, settings: str, unit: str, state: str) -> Optional[dict]:
    """The result document at ``path`` if it is one of this input file (same SHA-256) made with the
    same settings (:func:`settings_sha256`), of this ``unit`` and ``state``, and as triadcal saved it
    (its ``content_sha256`` present and matching its content); else None, and the pair is fitted
    again. An outside probe: a stored result edited by 50 arcsec (its checksum left stale), and one
    unit's result copied over another's of the same input file, were both skipped as done on the
    rerun, "7 ok", the edited value and the other unit's values in the fleet summary and the history
    (which then had no calibration of the overwritten unit)."""
    if not path.exists():
        return None
    from ..estimation.result import CONTENT_HASH_KEY, content_sha256
    from ..io.atomic import read_json

    try:
        d = read_json(path)
    except InputError:
        return None
    b = d.get("batch") if isinstance(d, dict) else None
    if not (isinstance(b, dict) and b.get("input_sha256") == sha and b.get("settings_sha256") == settings):
        return None
    if str(d.get("unit")) != unit or str(b.get("state") or "") != state:
        return None
    sha_doc = d.get(CONTENT_HASH_KEY)
    try:
        intact = isinstance(sha_doc, str) and content_sha256(d) == sha_doc
    except (TypeError, ValueError):
        intact = False
    return d if intact else None


def calibration_date(campaign, lab=None) -> str:
    """The date the data were taken: the file's ``# date`` (capture writes it), else the lab
    file's ``[item] calibration_date``, else empty."""
    return str(campaign.metadata.get("date") or (lab.calibration_date if lab is not None else "") or "")


def read_input_bytes(path) -> bytes:
    """The bytes of an input, read once: they are hashed and parsed, so that the SHA-256 a result
    records is that of the data it was fitted on (a module-level function, so a test can stand
    between the read and the parse)."""
    with open(path, "rb") as fh:
        return fh.read()


def _decode_bench_csv(data: bytes, path: str) -> str:
    """The text of a bench CSV's bytes as :func:`triadcal.io.bench_csv.read_bench_csv` reads it
    (UTF-8 with an optional BOM, universal newlines)."""
    import io

    from ..io.bench_csv import BenchCSVError, text_line_of_offset

    try:
        data.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        bom = 3 if data.startswith(b"\xef\xbb\xbf") else 0
        raise BenchCSVError(path, text_line_of_offset(data, exc.start + bom), None, "not UTF-8 text") from None
    return io.TextIOWrapper(io.BytesIO(data), encoding="utf-8-sig").read()


def _file_error(input_path, message: str) -> dict:
    return {"unit": "", "state": "", "input": str(input_path), "path": "", "action": "error",
            "status": "refused", "error": message}


def _why(exc: BaseException) -> str:
    """An exception as an error row says it: an input error's own text; anything else with its
    type (a bug, a full disk: the pair is refused and named, the batch goes on)."""
    if isinstance(exc, InputError):
        return str(exc)
    if isinstance(exc, OSError) and exc.filename:
        return f"{exc.filename}: {exc.strerror or exc}"
    return f"{type(exc).__name__}: {exc}"


def _spellings(todo: list) -> dict:
    """(unit, state) pairs of one input that are one serial and state under :func:`same_name_key`
    but spelled differently (NFC and NFD): pair -> the other spellings."""
    groups: dict = {}
    for u, st in todo:
        groups.setdefault((same_name_key(u), same_name_key(st)), []).append((u, st))
    return {p: [q for q in g if q != p] for g in groups.values() if len(g) > 1 for p in g}


def fit_file_part(input_path: str, out_dir: str, part: int, n_parts: int, lab, options: FitOptions) -> list:
    """The task: read one bench CSV, fit its (unit, state) pairs ``part, part + n_parts, ...``
    that have no result yet, write each result as soon as it is fitted; return one record per
    pair: ``{"unit", "state", "input", "path", "action": "fitted" | "skipped" | "error", ...}``.
    Nothing it meets takes the batch down: a pair that fails (its fit, its result file) is that
    pair's error row, a file that fails is that file's (before, a serial too long for a file name
    raised in a worker and the batch exited 1 with no summary: an outside probe)."""
    from .manifest import is_manifest

    try:
        if is_manifest(input_path):
            return fit_manifest_part(input_path, out_dir, part, n_parts)
        return _fit_file_part(input_path, out_dir, part, n_parts, lab, options)
    except Exception as exc:       # noqa: BLE001 - refused and named, never the batch's end
        return [_file_error(input_path, f"{input_path}: not fitted: {_why(exc)}")]


def _fit_file_part(input_path: str, out_dir: str, part: int, n_parts: int, lab, options: FitOptions) -> list:
    try:          # one BLAS thread for the fits, without touching the process's environment
        from threadpoolctl import threadpool_limits
    except ImportError:          # pragma: no cover - threadpoolctl comes with scipy's stack
        threadpool_limits = None
    from ..api import fit
    from ..io.bench_csv import parse_bench_csv
    from .select import pair_mask, pairs

    try:
        # read once: the SHA-256 recorded and compared is that of the very bytes parsed and fitted
        # (a file replaced between a hash and a read gave a result with one version's SHA-256 and
        # the other's values, reused as done by the rerun: an outside probe)
        data = read_input_bytes(input_path)
    except OSError as exc:         # said by every part that meets it: one part may read, another not
        return [_file_error(input_path, f"{input_path}: cannot be read ({exc.strerror or exc})")]
    sha = hashlib.sha256(data).hexdigest()
    records = []
    try:
        campaign = parse_bench_csv(_decode_bench_csv(data, str(input_path)), str(input_path))
    except InputError as exc:       # said once, by part 0, not by every part of the file
        return [_file_error(input_path, str(exc))] if part == 0 else []
    todo = pairs(campaign)[part::n_parts]
    twins = _spellings(pairs(campaign))
    settings = settings_sha256(options.kwargs(), lab)
    for unit, state in todo:
        path = result_path(out_dir, unit, state)
        # the pair's first visit on the file's clock: a history records the states of a unit in the order
        # they were measured (an outside probe's initial/after-shock went in alphabetically, the shock backwards)
        first = campaign.time_s[pair_mask(campaign, unit, state)]
        rec = {"unit": unit, "state": state, "input": str(input_path), "path": str(path),
               "first_time_s": float(first.min()) if first.size else 0.0}
        if (unit, state) in twins:
            other = ", ".join(f"{u!a} in state {st!a}" for u, st in twins[(unit, state)])
            records.append({**rec, "action": "error", "status": "refused",
                            "error": f"{input_path}: unit {unit!a} in state {state!a} is also in this file as {other}: "
                                     "one serial in two Unicode forms (NFC and NFD); write it one way"})
            continue
        t0 = time.perf_counter()
        try:
            done = _existing(path, sha, settings, unit, state)
            if done is not None:
                records.append({**rec, "action": "skipped", "result": done})
                continue
            sub = campaign.select(pair_mask(campaign, unit, state), own_origin=True)
            if threadpool_limits is not None:
                with threadpool_limits(1):
                    result = fit(sub, lab=lab, **options.kwargs())
            else:                # pragma: no cover
                result = fit(sub, lab=lab, **options.kwargs())
            result.extra["batch"] = {"input": str(input_path), "input_sha256": sha, "settings_sha256": settings,
                                     "state": state,
                                     "date": calibration_date(campaign, lab),
                                     "lab": lab.name if lab is not None else ""}
            path.parent.mkdir(parents=True, exist_ok=True)
            result.save(path)
        except Exception as exc:   # noqa: BLE001 - this pair refused and named, the others go on
            records.append({**rec, "action": "error", "status": "refused", "error": _why(exc)})
            continue
        records.append({**rec, "action": "fitted", "seconds": time.perf_counter() - t0,
                        "result": _saved(path)})
    return records


def _saved(path) -> dict:
    """The result document as written (with its content_sha256): ``to_dict()`` has no checksum, and a
    history filled by ``batch --history`` marked every calibration 'not known to be the fit's answer'."""
    from ..io.atomic import read_json

    return read_json(path)


def _read_recording(data: bytes, e):
    """The raw recording of a manifest entry from its bytes (read once and hashed): parsed from a
    private copy of those bytes, the copy's name replaced by the recording's in the recording and
    in any refusal."""
    import dataclasses
    import tempfile

    from ..io.raw import read_raw_csv

    with tempfile.TemporaryDirectory(prefix="triadcal-batch-") as tmp:
        copy = Path(tmp) / (Path(e.path).name[-100:] or "recording.csv")
        copy.write_bytes(data)
        try:
            rec = read_raw_csv(str(copy), e.rate_hz, e.columns, e.unit, e.labels, None)
        except InputError as exc:
            raise InputError(str(exc).replace(str(copy), str(e.path))) from None
    return dataclasses.replace(rec, source=str(e.path))


def fit_manifest_part(manifest: str, out_dir: str, part: int, n_parts: int) -> list:
    """The task for a manifest of raw recordings: its entries ``part, part + n_parts, ...`` fitted
    with ``fit-raw`` (:func:`triadcal.estimation.raw.fit_raw`), each result written as soon as it
    is fitted, skipped when its result records the same recording (SHA-256 of the bytes read once,
    hashed and parsed)."""
    from ..estimation.raw import fit_raw
    from .manifest import read_manifest

    try:
        entries = read_manifest(manifest)[part::n_parts]
    except InputError as exc:       # said once, by part 0, not by every part of the manifest
        return [_file_error(manifest, str(exc))] if part == 0 else []
    records = []
    for e in entries:
        path = result_path(out_dir, e.serial, e.state)
        rec = {"unit": e.serial, "state": e.state, "input": str(e.path), "path": str(path)}
        t0 = time.perf_counter()
        try:
            data = read_input_bytes(e.path)
            sha = hashlib.sha256(data).hexdigest()
            settings = settings_sha256(e)
            done = _existing(path, sha, settings, e.serial, e.state)
            if done is not None:
                records.append({**rec, "action": "skipped", "result": done})
                continue
            out = fit_raw(_read_recording(data, e), e.rate_hz, columns=e.columns, unit=e.unit, poses=e.poses,
                          labels=e.labels, local_g_m_s2=e.local_g_m_s2, serial=e.serial)
            result = out.result
            result.extra["batch"] = {"input": str(e.path), "input_sha256": sha, "settings_sha256": settings,
                                     "state": e.state, "date": "",
                                     "lab": "", "manifest": str(manifest)}
            path.parent.mkdir(parents=True, exist_ok=True)
            result.save(path)
        except Exception as exc:   # noqa: BLE001 - this entry refused and named, the others go on
            records.append({**rec, "action": "error", "status": "refused", "error": _why(exc)})
            continue
        records.append({**rec, "action": "fitted", "seconds": time.perf_counter() - t0, "result": _saved(path)})
    return records


# -- one unit and state in one input only ------------------------------------------------------

def quick_pairs(path) -> list[tuple[str, str]]:
    """The (unit, state) pairs of an input, read cheaply before any fit: a manifest's entries, a
    bench CSV's ``unit`` and ``state`` columns (empty state: ``initial``, as the reader says).
    An input that cannot be read gives none here: its task reports the error."""
    import csv

    from .manifest import is_manifest, read_manifest

    try:
        if is_manifest(path):
            return [(e.serial, e.state) for e in read_manifest(path)]
        with open(path, encoding="utf-8", newline="") as fh:
            lines = (ln for ln in fh if ln.strip() and not ln.startswith("#"))
            rows = csv.reader(lines)
            header = [h.strip() for h in next(rows)]
            iu = header.index("unit")
            ist = header.index("state") if "state" in header else None
            out = set()
            for row in rows:
                if len(row) == len(header):
                    out.add((row[iu].strip(), (row[ist].strip() if ist is not None else "") or "initial"))
            return sorted(out)
    except (InputError, OSError, UnicodeDecodeError, ValueError, StopIteration, csv.Error):
        return []


def check_unique_pairs(files: Sequence[Path]) -> None:
    """Refuse inputs in which one unit and state (or two whose file names coincide) is in two
    files: one result file would hold one of the two fits, and the summary would count the unit
    twice (docs/fleet.md). Serials and states are compared as :func:`same_name_key` gives them
    (no surrounding spaces, Unicode NFC): ``SN-\u00c91`` in one file and ``SN-E\u03011`` (NFD) in
    another were fitted as two units whose rows print identically (an outside probe); one serial
    in two forms in one file is refused too."""
    where: dict = {}
    clashes = []
    for f in files:
        for unit, state in quick_pairs(f):
            for key in ((same_name_key(unit), same_name_key(state)), result_path("", unit, state)):
                if key not in where:
                    where[key] = (str(f), unit, state)
                    continue
                first = where[key]
                if first[0] == str(f) and first[1:] == (unit, state):
                    continue
                if first[1:] == (unit, state):
                    how = ""
                elif isinstance(key, tuple):
                    how = (f" (as {first[1]!a} in state {first[2]!a} there and {unit!a} in state {state!a} here: one "
                           "serial and state in two Unicode forms, NFC and NFD)")
                else:
                    how = f" (as {first[1]}/{first[2]}: one result file name)"
                clashes.append(f"unit {unit} in state {state} is in {first[0]} and in {f}{how}")
                break
    if clashes:
        raise InputError(f"{clashes[0]}" + (f" (and {len(clashes) - 1} more)" if len(clashes) > 1 else "")
                         + ": one result file would hold one of the two fits; give each unit and state in one "
                           "input only")


# -- the batch -------------------------------------------------------------------------------

@dataclass
class BatchReport:
    """What a batch did: one record per (unit, state) (see :func:`fit_file_part`), the files
    of the summary, the flags."""

    out_dir: Path
    records: list = field(default_factory=list)
    files: dict = field(default_factory=dict)
    flags: dict = field(default_factory=dict)
    warnings: list = field(default_factory=list)
    seconds: float = 0.0

    def count(self, action: str) -> int:
        return sum(1 for r in self.records if r["action"] == action)

    @property
    def n_fitted(self) -> int:
        return self.count("fitted")

    @property
    def n_skipped(self) -> int:
        return self.count("skipped")

    @property
    def n_errors(self) -> int:
        return self.count("error")

    @property
    def all_ok(self) -> bool:
        return all(r["action"] != "error" and r["result"]["status"] == "ok" for r in self.records)


def plan_tasks(files: Sequence[Path], n_workers: int) -> list[tuple[str, int, int]]:
    """(file, part, n_parts) of every task: whole files, or each file in parts when there are
    fewer files than twice the workers."""
    n_parts = 1 if len(files) >= 2 * n_workers else math.ceil(2 * n_workers / len(files))
    return [(str(f), i, n_parts) for f in files for i in range(n_parts)]


def start_client(scheduler: Optional[str] = None, workers: int = 2, processes: bool = True):
    """A dask.distributed client: of a running scheduler at ``scheduler`` (its workers should
    run with OMP_NUM_THREADS=1), else of a new LocalCluster of ``workers`` processes (or
    threads with ``processes=False``), one thread each, one BLAS thread each. Returns
    ``(client, cluster or None)``."""
    from dask.distributed import Client, LocalCluster

    if scheduler:
        return Client(scheduler), None
    if workers < 1:
        raise InputError(f"--workers must be at least 1, got {workers}")
    kw = {"env": dict(WORKER_ENV)} if processes else {}   # the workers' own environment, not ours
    cluster = LocalCluster(n_workers=workers, threads_per_worker=1, processes=processes,
                           dashboard_address=None, **kw)
    return Client(cluster), cluster


def batch(inputs: Sequence, out_dir, *, lab=None, scheduler: Optional[str] = None, workers: int = 2,
          processes: bool = True, tolerances=None, history=None, options: FitOptions = FitOptions(),
          client=None, html: bool = True, progress: Optional[Callable[[dict], None]] = None) -> BatchReport:
    """Fit every (unit, state) of ``inputs`` (bench CSV files or glob patterns) into
    ``out_dir/results/<unit>__<state>.json`` and write the fleet summary (``fleet.csv``,
    ``fleet.parquet``, ``fleet.html``, :mod:`triadcal.fleet.summary`).

    ``lab``: lab file (path or LabConfig) given to every fit. ``scheduler``: address of a
    running dask scheduler; else a LocalCluster of ``workers`` (``processes=False``: threads).
    ``client``: an existing dask Client to use instead (not closed). ``tolerances``: a
    tolerance file (TOML) whose limits flag units. ``history``: an SQLite history database
    into which every result of the batch is recorded. ``progress``: called with each record
    as its task completes. ``html=False``: no fleet.html (its histograms take ~0.1 s each)."""
    from ..io.lab import LabConfig, load_lab

    t0 = time.perf_counter()
    files, unreadable = find_inputs(inputs)
    check_unique_pairs(files)                  # one unit and state in two inputs: refused before any fit
    if lab is not None and not isinstance(lab, LabConfig):
        lab = load_lab(lab)
    tol = None
    if tolerances is not None:
        from .summary import load_tolerances

        tol = load_tolerances(tolerances)      # refused before any fit
    if history is not None:
        from .history import HistoryDB

        HistoryDB(history).close()             # a corrupt or foreign database is refused before any fit
    out_dir = Path(out_dir)
    (out_dir / "results").mkdir(parents=True, exist_ok=True)

    # a glob match that is not a readable file is one error row (it was dropped without a word)
    records = [_file_error(m, f"{m}: {why}: not fitted") for m, why in unreadable]
    if progress is not None:
        for r in records:
            progress(r)
    own = client is None and bool(files)
    cluster = None
    if own:
        client, cluster = start_client(scheduler, workers, processes)
    try:
        if files:
            from dask.distributed import as_completed

            n_workers = max(1, len(client.scheduler_info().get("workers", {})) or workers)
            tasks = plan_tasks(files, n_workers)
            # absolute paths to the workers: a worker of an external scheduler has its own working directory
            # (an outside probe: --out outS2 relative, "results in outS2/results" printed, the 8 results
            # written under the worker's folder and the client's left empty; relative inputs not found)
            where = str(out_dir.resolve())
            futures = {client.submit(fit_file_part, str(Path(f).resolve()), where, i, k, lab, options, pure=False):
                       (f, i, k) for f, i, k in tasks}
            said = set()
            for fut in as_completed(list(futures)):
                try:
                    recs = fut.result()
                except Exception as exc:     # noqa: BLE001 - a task lost (a worker killed): its file's error row
                    f, i, k = futures[fut]
                    recs = [_file_error(f, f"{f}: not fitted" + (f" (part {i + 1} of {k})" if k > 1 else "")
                                        + f": the task failed: {_why(exc)}")]
                # a file that cannot be read is said by each part that met it: one row
                recs = [r for r in recs if r["unit"] or (r["input"], r["error"]) not in said]
                said.update((r["input"], r["error"]) for r in recs if not r["unit"] and r["action"] == "error")
                records.extend(recs)
                if progress is not None:
                    for r in recs:
                        progress(r)
    finally:
        if own:
            client.close()
            if cluster is not None:
                cluster.close()
    # a pair in two input files (or two names that map to one file name): the last one written wins
    seen, warnings = {}, []
    for r in records:
        if r["action"] != "error":
            if r["path"] in seen and seen[r["path"]] != r["input"]:
                warnings.append(f"unit {r['unit']} in state {r['state']} is in {seen[r['path']]} and in "
                                f"{r['input']}: one result file ({r['path']}) holds the last fitted")
            seen[r["path"]] = r["input"]
    records.sort(key=lambda r: (r["unit"], r["state"], r["input"]))
    report = BatchReport(out_dir=out_dir, records=records, warnings=warnings)
    from .summary import write_summary

    report.files, report.flags = write_summary(records, out_dir, tol, html_page=html)
    report.warnings.extend(report.flags.get("tolerances_unmatched", []))
    if history is not None:
        from .history import HistoryDB

        with HistoryDB(history) as db:
            # one unit's states in the order they were measured (same date: the history keeps record order)
            for r in sorted(records, key=lambda r: (r["unit"], str((r.get("result") or {}).get("batch", {}).get("date")
                                                                   or ""), r["input"], r.get("first_time_s", 0.0))):
                if r["action"] != "error":
                    db.add(r["result"], lab=lab)
    report.seconds = time.perf_counter() - t0
    return report
