"""An output file in a folder that does not exist is refused before any work, naming the folder
(a newcomer's probe: the error named an internal '.r.json.xyz.part' file after the work was done,
and `sample --posterior nodir/p.nc` wrote its result JSON, then failed)."""

import pytest

from triadcal.cli import main
from triadcal.io.atomic import atomic_write_text, check_output_folder
from triadcal.errors import InputError


@pytest.mark.parametrize("argv", [["fit", "{data}", "--json", "{tmp}/nodir/r.json"],
                                  ["sample", "{data}", "--json", "{tmp}/r.json", "--posterior", "{tmp}/nodir/p.nc"],
                                  ["budget", "--json", "{tmp}/nodir/b.json"]])
def test_a_missing_output_folder_is_refused_first(tmp_path, capsys, argv):
    from triadcal.api import example_path

    argv = [a.format(data=example_path(), tmp=tmp_path) for a in argv]
    assert main(argv) == 1
    err = capsys.readouterr().err
    assert "nodir: the folder" in err or "the folder" in err and "does not exist" in err, err
    assert ".part" not in err
    assert not (tmp_path / "r.json").exists()          # nothing written before the refusal


def test_the_writer_names_the_folder_too(tmp_path):
    with pytest.raises(InputError, match="the folder .*nodir does not exist"):
        atomic_write_text(tmp_path / "nodir" / "x.txt", "x")
    (tmp_path / "file").write_text("x")
    with pytest.raises(InputError, match="is not a folder"):
        check_output_folder(tmp_path / "file" / "x.txt")
