"""What an existing output may be replaced with --overwrite: a dataset or an empty folder, never what else
a folder holds (a typo in --output, the bags' own folder)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bagport.dataset.replace import refuse_existing, refuse_output_in_a_bag
from bagport.errors import DatasetWriteError, OutputInBagError


def test_a_missing_output_is_free_and_an_existing_one_needs_overwrite(tmp_path: Path) -> None:
    refuse_existing(str(tmp_path / "new"), overwrite=False)
    with pytest.raises(DatasetWriteError, match="already exists; nothing was written"):
        refuse_existing(str(tmp_path), overwrite=False)


def test_overwrite_replaces_a_dataset_or_an_empty_folder(tmp_path: Path) -> None:
    empty = tmp_path / "empty"
    empty.mkdir()
    refuse_existing(str(empty), overwrite=True)
    dataset = tmp_path / "ds"
    (dataset / "meta").mkdir(parents=True)
    (dataset / "meta/info.json").write_text("{}")
    (dataset / "data").mkdir()
    refuse_existing(str(dataset), overwrite=True, inputs=[str(tmp_path / "bags/a.mcap")])


def test_overwrite_refuses_a_folder_that_is_not_a_dataset_and_keeps_it(tmp_path: Path) -> None:
    folder = tmp_path / "important"
    folder.mkdir()
    (folder / "notes.txt").write_text("precious")
    with pytest.raises(DatasetWriteError, match=r"is not a dataset \(no meta/info\.json\)") as err:
        refuse_existing(str(folder), overwrite=True)
    assert "Fix: choose a new --output" in str(err.value)
    assert (folder / "notes.txt").read_text() == "precious"
    a_file = tmp_path / "file.parquet"
    a_file.write_bytes(b"x")
    with pytest.raises(DatasetWriteError, match="is not a dataset"):
        refuse_existing(str(a_file), overwrite=True)


def test_overwrite_refuses_a_dataset_that_holds_a_bag_of_the_run(tmp_path: Path) -> None:
    dataset = tmp_path / "ds"
    (dataset / "meta").mkdir(parents=True)
    (dataset / "meta/info.json").write_text("{}")
    bag = dataset / "bags/ep0"
    with pytest.raises(DatasetWriteError, match=r"holds the bag .*ep0, and --overwrite would remove it"):
        refuse_existing(str(dataset), overwrite=True, inputs=[str(tmp_path / "elsewhere"), str(bag)])
    # a sibling whose name starts like the dataset's is not inside it
    refuse_existing(str(dataset), overwrite=True, inputs=[str(tmp_path / "ds-bags/ep0")])


def test_overwrite_sees_a_bag_inside_the_dataset_through_dots_and_links(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    dataset = tmp_path / "ds"
    (dataset / "meta").mkdir(parents=True)
    (dataset / "meta/info.json").write_text("{}")
    (dataset / "bags").mkdir()
    (tmp_path / "sub").mkdir()
    monkeypatch.chdir(tmp_path / "sub")
    with pytest.raises(DatasetWriteError, match="holds the bag"):  # --output ../ds
        refuse_existing("../ds", overwrite=True, inputs=[str(dataset / "bags/a.mcap")])
    (tmp_path / "link").symlink_to(dataset / "bags")
    with pytest.raises(DatasetWriteError, match="holds the bag"):  # the bag named through a link
        refuse_existing(str(dataset), overwrite=True, inputs=[str(tmp_path / "link/a.mcap")])


def test_an_output_in_a_bag_of_the_run_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The converse of a dataset holding a bag: a dataset written into a recording's folder."""
    bag = tmp_path / "bags/ep1"
    bag.mkdir(parents=True)
    inputs = [str(tmp_path / "bags/other.mcap"), str(bag)]
    for output in (bag / "out", bag, bag / "deeper/out"):
        with pytest.raises(OutputInBagError, match=rf"--output {output} is inside the bag {bag}:") as caught:
            refuse_output_in_a_bag(str(output), inputs)
        assert "nothing was written. Fix: choose a --output outside the bags' folders." in str(caught.value)
        assert (caught.value.option, caught.value.path, caught.value.bag_uri) == (
            "--output",
            str(output),
            str(bag),
        )
        assert isinstance(caught.value, DatasetWriteError)  # a write error like the others (exit code 2)
    monkeypatch.chdir(bag)
    with pytest.raises(DatasetWriteError, match="is inside the bag"):  # --output out, run from the bag
        refuse_output_in_a_bag("out", inputs)
    (tmp_path / "link").symlink_to(bag)
    with pytest.raises(DatasetWriteError, match="is inside the bag"):  # through a link
        refuse_output_in_a_bag(str(tmp_path / "link/out"), inputs)
    # beside the bags, or a sibling whose name starts like the bag's, is not inside one
    refuse_output_in_a_bag(str(tmp_path / "bags/ep1-dataset"), inputs)
    refuse_output_in_a_bag(str(tmp_path / "datasets/ep1"), inputs)
    with pytest.raises(
        OutputInBagError, match=rf"--staging {bag}/st is inside the bag {bag}: the staged episodes"
    ) as caught:
        refuse_output_in_a_bag(str(bag / "st"), inputs, "--staging")
    assert (caught.value.option, caught.value.bag_uri) == ("--staging", str(bag))
