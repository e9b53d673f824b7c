"""Output files (issue 64, items 4, 5, 10, 13): one file per id whatever its characters, output places checked
before any work, the user's umask, and a survey report whose per-id maps are bounded and listed in summary.md."""
import json
import os
import stat
from pathlib import Path

import pytest

from aoa_localizer.common.output import NAME_MAX_CHARS, StagedFile, check_folder, check_output, file_names
from aoa_localizer.tools import locate

SURVEY = ["1700000000,47.000,8.000,45", "1700000060,47.000,8.010,315", "1700000120,46.990,8.005,10"]


def survey(path: Path, idents) -> Path:
    """Three stations around one place, heard for each id."""
    rows = ["time,lat,lon,azimuth_deg,station,id"]
    for ident in idents:
        rows += [f"{r},s{k},{ident}" for k, r in enumerate(SURVEY)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_ids_that_once_shared_a_file_name_get_one_each():
    """`a/b`, `a_b`, `a:b`, `a\\b` all became `a_b` (15 ids gave 12 .cot files); `A` and `a` collide where a file
    system ignores case; 300 characters were `File name too long`."""
    ids = ["a/b", "a_b", "a:b", "a\\b", "A", "a", "x" * 300, "y" * 300, ".hidden", "..", "", "f433920000", "ü"]
    names = file_names(ids)
    assert len({n.casefold() for n in names.values()}) == len(ids)
    assert names["f433920000"] == "f433920000" and names["a_b"] == "a_b"  # a plain name is kept as it is
    for name in names.values():
        assert name and not name.startswith(".") and len(name) <= NAME_MAX_CHARS and "/" not in name
        assert all(c.isascii() and (c.isalnum() or c in "-_.") for c in name)
    assert file_names(reversed(ids)) == names  # the same id, the same name, whatever else the file holds


@pytest.mark.slow
def test_a_survey_report_has_a_file_per_id_and_a_summary_naming_them(tmp_path, capsys):
    ids = ["a/b", "a_b", "a:b", "a\\b", "z" * 300, "tx\x01"]
    path = survey(tmp_path / "s.csv", ids)
    assert locate.main([str(path), "--report", str(tmp_path / "rep"), "--maps", "4"]) == 0
    err = capsys.readouterr().err
    rep = tmp_path / "rep"
    assert len(list(rep.glob("emitter_*.cot"))) == len(ids) and f"{len(ids)} .cot files" in err
    assert len(list((rep / "maps").glob("*.png"))) == 4
    assert "maps/ holds the first 4 of 6 ids" in err
    summary = (rep / "summary.md").read_text()
    for name in file_names(ids).values():
        assert f"emitter_{name}.cot" in summary
    assert summary.count("not drawn (--maps)") == 2 and "tx\\u0001" in summary


def test_an_output_that_cannot_be_written_is_refused_before_any_work(tmp_path):
    """Into a path under a regular file, into /proc, onto /proc/self/mem: tracebacks after all the work before."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    for bad in (blocker / "rep", blocker / "a" / "b", Path("/proc/aoa_report")):
        with pytest.raises(ValueError, match="--report"):
            check_folder(bad, "--report")
    with pytest.raises(ValueError, match="exists"):
        check_folder(tmp_path, "--record", new=True)
    for bad in (Path("/proc/self/mem"), blocker / "out.jsonl", Path("/dev/null")):
        with pytest.raises(ValueError, match="--output"):
            check_output(bad)
    check_folder(tmp_path / "new" / "deeper", "--report")  # a folder to be made is fine, and is not made yet
    assert not (tmp_path / "new").exists()
    check_output(tmp_path / "out.jsonl")


@pytest.mark.parametrize("args", [["--report", "{file}/rep"], ["--output", "/proc/self/mem"],
                                  ["--report", "/proc/aoa_report"]])
def test_locate_refuses_such_outputs_with_exit_2_and_one_line(tmp_path, capsys, args):
    path = survey(tmp_path / "s.csv", ["tx"])
    (tmp_path / "file").write_text("x")
    args = [a.format(file=tmp_path / "file") for a in args]
    assert locate.main([str(path), *args]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith(f"locate: {args[0]}") and "Traceback" not in err[0]


def test_a_staged_output_gets_the_users_umask_not_0600(tmp_path):
    old = os.umask(0o022)
    try:
        with StagedFile(tmp_path / "o.jsonl") as staged:
            staged.file.write("{}\n")
            staged.keep()
        os.umask(0o027)
        with StagedFile(tmp_path / "p.jsonl") as staged:
            staged.keep()
    finally:
        os.umask(old)
    assert stat.S_IMODE((tmp_path / "o.jsonl").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "p.jsonl").stat().st_mode) == 0o640


def test_locates_lines_are_written_as_each_id_is_done(tmp_path, capsys):
    """Each id's line is in --output when its row is on the table (the file placed at the first id)."""
    path = survey(tmp_path / "s.csv", ["one", "two"])
    assert locate.main([str(path), "--output", str(tmp_path / "o.jsonl")]) == 0
    assert [json.loads(line)["id"] for line in (tmp_path / "o.jsonl").read_text().splitlines()] == ["one", "two"]
    assert stat.S_IMODE((tmp_path / "o.jsonl").stat().st_mode) == 0o666 & ~_umask()


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask
