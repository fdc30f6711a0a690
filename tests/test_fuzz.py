"""Run the fuzz corpus (tests/fuzz_corpus.py) through the CLI in-process: 0 tracebacks, 0
internal errors, 0 "ok" on an invalid input, and every refusal names its file and the line or
field where one exists."""

import json
import re
from collections import Counter

import pytest

from triadcal.cli import main

from fuzz_corpus import generate


@pytest.fixture(scope="module")
def corpus(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz-seed")
    assert main(["fit", "--example", "--json", str(d / "good.json")]) == 0
    assert main(["compare", str(d / "good.json"), str(d / "good.json"), "--json", str(d / "comp.json")]) == 0
    good = json.loads((d / "good.json").read_text())
    comp = json.loads((d / "comp.json").read_text())
    return generate(good, comp)


def test_the_corpus_is_large_and_covers_every_kind(corpus):
    assert len(corpus) >= 300
    kinds = Counter(c.name.split("-")[0] for c in corpus)
    assert {"bench", "raw", "certificate", "compare", "drift", "published"} <= set(kinds), kinds
    assert sum(c.expected != "any" for c in corpus) >= 250


def _run(case, tmp_path, capsys):
    d = tmp_path / case.name.replace("/", "_")[:80]
    d.mkdir()
    for name, data in case.files.items():
        (d / name).write_bytes(data)
    argv = [a.replace("{dir}", str(d)) for a in case.argv]
    code = main(argv)
    out, err = capsys.readouterr()
    return d, code, out, err


def test_every_case(corpus, tmp_path, capsys):
    problems = []
    outcomes = Counter()
    for case in corpus:
        d, code, out, err = _run(case, tmp_path, capsys)
        text = out + err
        outcomes[(case.expected, code)] += 1
        why = []
        if "Traceback" in text or code == 70 or "internal error" in text:
            why.append("traceback/internal error")
        if case.expected == "refused":
            if code != 1:
                why.append(f"expected a refusal (exit 1), got exit {code}")
            else:
                if case.main_file and str(d / case.main_file) not in err:
                    why.append("the refusal does not name the file")
                for w in case.where:
                    if w not in err:
                        why.append(f"the refusal does not say {w!r}")
        elif case.expected == "not_ok":
            if code not in (1, 3):
                why.append(f"expected not ok (exit 3) or a refusal, got exit {code}")
        elif code not in (0, 1, 3):
            why.append(f"unexpected exit {code}")
        if case.expected != "any" and (re.search(r"status ok\b", out) or "overall: pass" in out
                                       or re.search(r"^certificate \S+ issued", out, re.M)):
            why.append("says ok on an invalid input")
        if why:
            problems.append(f"{case.name}: {'; '.join(why)} | exit {code} | {err.strip()[:300]}")
    assert not problems, f"{len(problems)} of {len(corpus)} cases failed:\n" + "\n".join(problems)
    # every invalid input was refused or said not ok
    assert outcomes[("refused", 0)] == 0 and outcomes[("not_ok", 0)] == 0
