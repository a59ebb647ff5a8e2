"""What `vtestbed dataset import` writes where: never over a file that was there, never two clouds
to one dataset file, nothing left behind by a refused input.

References: the files themselves (bytes before and after), the manifest's test ids and the
dataset's naming rule (``clouds/<id>_<state>.ply``, ``clouds/<id>_loaded_repeat<k>.ply``).
"""

from __future__ import annotations

import shutil

from test_lab_import import _replace, lab_files, simulated  # noqa: F401  (fixtures)

from vtestbed.cli.main import main


def _import(manifest, out, capsys) -> tuple[int, str]:
    code = main(["dataset", "import", str(manifest), "--out", str(out)])
    return code, capsys.readouterr().err


def test_a_cloud_file_already_in_the_output_is_refused_and_kept(lab_files, tmp_path, capsys):  # noqa: F811
    """A scan kept where the import would write (here a lab's own PLY in out/clouds) is refused
    before anything is read or written, and is still there, byte for byte."""
    out = tmp_path / "out"
    (out / "clouds").mkdir(parents=True)
    kept = out / "clouds" / "T002_loaded.ply"
    kept.write_bytes(b"a lab's own scan")
    code, err = _import(lab_files / "manifest.toml", out, capsys)
    assert code == 2 and "Traceback" not in err, err
    assert f"{kept} already exists: dataset import writes only new files" in err
    assert kept.read_bytes() == b"a lab's own scan"
    assert sorted(p.name for p in out.rglob("*")) == ["T002_loaded.ply", "clouds"]


def test_two_clouds_named_alike_in_the_dataset_are_refused(lab_files, tmp_path, capsys):  # noqa: F811
    """Test ``T001`` scanned loaded again, and a test ``T001_loaded`` with a repeat of its unloaded
    block: both would be ``clouds/T001_loaded_repeat1.ply``; refused naming both fields."""
    lab = tmp_path / "lab"
    shutil.copytree(lab_files, lab)
    manifest = lab / "manifest.toml"
    text = manifest.read_text()
    first = text.index("[[tests]]", text.index('id = "T002"') - 20)
    second = text.index("[[tests]]", first + 1)
    block = text[first:second]
    assert "loaded_repeat_clouds" in text[: text.index('id = "T002"')]  # T001 has a loaded repeat
    renamed = block.replace('id = "T002"', 'id = "T001_loaded"')
    _replace(manifest, block, renamed)
    code, err = _import(manifest, tmp_path / "out", capsys)
    assert code == 2 and "Traceback" not in err, err
    assert (
        "tests[1].repeat_clouds[0]: would be written to the dataset's clouds/T001_loaded_repeat1.ply" in err
    )
    assert "as tests[0].loaded_repeat_clouds[0] is" in err
    assert not (tmp_path / "out").exists()


def test_a_failure_while_writing_the_dataset_files_leaves_nothing_it_wrote(lab_files, tmp_path, capsys):  # noqa: F811
    """Every cloud read and converted, then writing ft_windows.csv fails (a folder of that name is
    in the way, as a full disk would fail it): setup.json, tests.csv, the repeats files and every
    converted cloud are removed again, and the folder in the way is kept; a clean import of the
    same manifest then writes a whole dataset (its file count: the manifest's clouds)."""
    out = tmp_path / "out"
    (out / "ft_windows.csv").mkdir(parents=True)
    code, err = _import(lab_files / "manifest.toml", out, capsys)
    assert code == 1 and "Traceback" not in err, err
    assert "ft_windows.csv" in err
    assert sorted(p.name for p in out.rglob("*")) == ["ft_windows.csv"]
    (out / "ft_windows.csv").rmdir()
    code, err = _import(lab_files / "manifest.toml", out, capsys)
    assert code == 0, err
    text = (lab_files / "manifest.toml").read_text()
    n_clouds = text.count(".ply") + text.count(".pcd") + text.count(".xyz")
    assert len(list((out / "clouds").iterdir())) == n_clouds
