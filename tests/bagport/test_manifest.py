"""Manifests: relative paths, globs, fsspec URIs; every error names the entry."""

from __future__ import annotations

from pathlib import Path

import fsspec
import pytest

from bagport.errors import ManifestError
from bagport.manifest import load_manifest, parse_manifest
from bagport.timewindow import TimeWindow


def _touch(path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(b"x")
    return path


def test_relative_paths_globs_and_defaults(tmp_path: Path) -> None:
    _touch(tmp_path / "bags/a.mcap")
    _touch(tmp_path / "bags/b.mcap")
    (tmp_path / "bags/folder_bag").mkdir()
    manifest = tmp_path / "m.yaml"
    manifest.write_text(
        "bags:\n"
        "  - uri: bags/folder_bag\n    task: fold the towel\n    metadata: {operator: alice}\n"
        "  - uri: bags/*.mcap\n"
    )
    loaded = load_manifest(str(manifest))
    assert [Path(b.uri).name for b in loaded.bags] == ["folder_bag", "a.mcap", "b.mcap"]
    assert loaded.bags[0].task == "fold the towel"
    assert loaded.bags[0].metadata == {"operator": "alice"}
    assert [b.entry for b in loaded.bags] == [0, 1, 1]
    assert all(Path(b.uri).is_absolute() for b in loaded.bags)


def test_fsspec_uris(tmp_path: Path) -> None:
    fs = fsspec.filesystem("memory")
    fs.pipe("/fleet/day1/ep1.mcap", b"x")
    fs.pipe("/fleet/day1/ep2.mcap", b"x")
    loaded = parse_manifest("bags:\n  - uri: memory://fleet/day1/*.mcap\n", "m.yaml")
    assert [b.uri for b in loaded.bags] == ["memory:///fleet/day1/ep1.mcap", "memory:///fleet/day1/ep2.mcap"]


@pytest.mark.parametrize(
    ("text", "match"),
    [
        pytest.param(
            "bags:\n  - uri: nope.mcap\n",
            r"m\.yaml, bags\[0\]: bag '.*nope\.mcap' does not exist.*Fix:",
            id="missing",
        ),
        pytest.param("bags:\n  - uri: '*.nothing'\n", r"bags\[0\]: glob .* matches no bag", id="empty-glob"),
        pytest.param("bags: []\n", r"at least 1", id="empty"),
        pytest.param(
            "bag:\n  - uri: x\n", r"line 1: bag: unknown field.*Fix: did you mean 'bags'", id="typo-top"
        ),
        pytest.param(
            "bags:\n  - url: a.mcap\n",
            r"bags\[0\]: line 2: url: unknown field.*Fix: did you mean 'uri'",
            id="typo-uri",
        ),
        pytest.param("bags:\n  - {uri: a.mcap}\n  - {url: b.mcap}\n", r"bags\[1\].*line 3", id="entry-field"),
        pytest.param("bags: [\n", r"not valid YAML", id="bad-yaml"),
        pytest.param(
            "bags:\n  - {uri: a.mcap, start_s: 1, start_ns: 5}\n",
            r"bags\[0\].*start_s .* or start_ns",
            id="two-starts",
        ),
        pytest.param(
            "bags:\n  - {uri: a.mcap, start_s: 4, end_s: 2}\n",
            r"ends \(end_s 2.0\) at or before it starts \(start_s 4.0\)",
            id="backwards",
        ),
        pytest.param(
            "bags:\n  - {uri: a.mcap, end_s: -1}\n", r"end_s: Input should be greater than 0", id="negative"
        ),
        pytest.param(
            "bags:\n  - uri: a.mcap\n    metadata: {robot_id: arm-1, raw: !!binary aGk=}\n",
            r"bags\[0\]: line 3: metadata\.raw: .*not a valid JSON value.*Fix: .*JSON values",
            id="metadata-not-json",
        ),
    ],
)
def test_manifest_errors_name_the_entry(tmp_path: Path, text: str, match: str) -> None:
    _touch(tmp_path / "a.mcap")
    with pytest.raises(ManifestError, match=match):
        parse_manifest(text, "m.yaml", base_dir=str(tmp_path))


@pytest.mark.parametrize(
    ("text", "where", "message"),
    [
        pytest.param(
            "bags:\n  - uri: a.mcap\n    start_s: 1\n    start_ns: 5\n",
            (0, 4),
            "m.yaml, bags[0]: line 4: gives both start_s (seconds from the bag's first message) and start_ns "
            "(ROS time): start_s on line 3, start_ns on line 4 Fix: keep one of the two: remove start_s or start_ns.",
            id="two-starts",
        ),
        pytest.param(
            "bags:\n  - uri: a.mcap\n  - uri: a.mcap\n    end_ns: 5\n    task: t\n    end_s: 1\n",
            (1, 6),
            "m.yaml, bags[1]: line 6: gives both end_s (seconds from the bag's first message) and end_ns "
            "(ROS time): end_ns on line 4, end_s on line 6 Fix: keep one of the two: remove end_s or end_ns.",
            id="two-ends-later-first",
        ),
        pytest.param(
            "bags:\n  - uri: a.mcap\n    start_ns: 9\n    end_ns: 9\n",
            (0, 4),
            "m.yaml, bags[0]: line 4: the window ends (end_ns 9) at or before it starts (start_ns 9): start_ns on "
            "line 3, end_ns on line 4 Fix: give an end_ns greater than start_ns, or leave one of them out (the "
            "bag's start or end).",
            id="empty-window",
        ),
    ],
)
def test_two_keys_that_clash_name_the_entry_once_and_the_later_line(
    tmp_path: Path, text: str, where: tuple[int, int], message: str
) -> None:
    """Both clocks for one end, or an end at or before the start: the error names the entry once, points at
    the later of the two keys (both lines given) and says which key to keep, not the manifest's format."""
    _touch(tmp_path / "a.mcap")
    with pytest.raises(ManifestError) as caught:
        parse_manifest(text, "m.yaml", base_dir=str(tmp_path))
    assert str(caught.value) == message
    assert (caught.value.entry, caught.value.line) == where


def test_metadata_dates_are_read_as_text(tmp_path: Path) -> None:
    """YAML reads an unquoted ``2026-11-02`` as a date: metadata holds JSON values, so it is kept as text."""
    _touch(tmp_path / "a.mcap")
    text = "bags:\n  - uri: a.mcap\n    metadata: {day: 2026-11-02, at: [2026-11-02 10:30:00], n: 3}\n"
    bag = parse_manifest(text, "m.yaml", base_dir=str(tmp_path)).bags[0]
    assert bag.metadata == {"day": "2026-11-02", "at": ["2026-11-02 10:30:00"], "n": 3}


def test_duplicate_bag_is_an_error(tmp_path: Path) -> None:
    _touch(tmp_path / "a.mcap")
    with pytest.raises(ManifestError, match=r"bags\[1\]: bag .* is listed twice"):
        parse_manifest("bags:\n  - uri: a.mcap\n  - uri: '*.mcap'\n", "m.yaml", base_dir=str(tmp_path))


def test_a_bag_may_be_listed_once_per_window(tmp_path: Path) -> None:
    _touch(tmp_path / "a.mcap")
    text = (
        "bags:\n  - {uri: a.mcap, end_s: 10}\n  - {uri: a.mcap, start_s: 10, task: second}\n  - uri: a.mcap\n"
    )
    manifest = parse_manifest(text, "m.yaml", base_dir=str(tmp_path))
    assert [(b.window, b.task) for b in manifest.bags] == [
        (TimeWindow(end_s=10.0), None),
        (TimeWindow(start_s=10.0), "second"),
        (TimeWindow(), None),
    ]
    with pytest.raises(ManifestError, match=r"bags\[1\]: bag .* is listed twice \(also bags\[0\]\)"):
        parse_manifest(
            text.replace("start_s: 10, task: second", "end_s: 10"), "m.yaml", base_dir=str(tmp_path)
        )


def test_missing_manifest_file() -> None:
    with pytest.raises(ManifestError, match="does not exist"):
        load_manifest("/no/such/manifest.yaml")


def test_relative_uris_in_a_remote_manifest() -> None:
    fs = fsspec.filesystem("memory")
    fs.pipe("/fleet2/day/ep.mcap", b"x")
    fs.pipe("/fleet2/manifest.yaml", b"bags:\n  - uri: day/ep.mcap\n")
    assert [b.uri for b in load_manifest("memory://fleet2/manifest.yaml").bags] == [
        "memory://fleet2/day/ep.mcap"
    ]


def test_a_manifest_that_is_not_text_an_infinite_window_or_a_folder_is_one_paragraph(tmp_path: Path) -> None:
    """Fuzzed inputs that escaped as UnicodeDecodeError, OverflowError and IsADirectoryError."""
    latin1 = tmp_path / "m.yaml"
    latin1.write_bytes("bags:\n  - {uri: bags/épisode}\n".encode("latin-1"))
    with pytest.raises(ManifestError, match=r"is not UTF-8 text \(the byte at offset 21 is not\).*iconv"):
        load_manifest(str(latin1))
    endless = tmp_path / "inf.yaml"
    endless.write_text("bags:\n  - {uri: b, end_s: .inf}\n")
    with pytest.raises(ManifestError, match="end_s: Input should be a finite number"):
        load_manifest(str(endless))
    with pytest.raises(ManifestError, match=r"cannot be read \(Is a directory\)"):
        load_manifest(str(tmp_path))


@pytest.mark.parametrize(
    ("text", "entry", "line", "key"),
    [
        pytest.param("bags:\n  - uri: a.mcap\n    uri: b.mcap\n", 0, 3, "uri", id="uri-twice"),
        pytest.param("bags:\n  - uri: a.mcap\nbags:\n  - uri: b.mcap\n", None, 3, "bags", id="bags-twice"),
        pytest.param(
            "bags:\n  - uri: a.mcap\n  - uri: b.mcap\n    metadata: {op: alice, op: bob}\n",
            1,
            4,
            "op",
            id="metadata-key-twice",
        ),
    ],
)
def test_a_key_given_twice_names_the_entry_and_its_line(
    tmp_path: Path, text: str, entry: int | None, line: int, key: str
) -> None:
    """YAML keeps the last of two equal keys without a word: a manifest refuses them."""
    _touch(tmp_path / "a.mcap")
    _touch(tmp_path / "b.mcap")
    with pytest.raises(ManifestError, match=rf"key '{key}' is given twice") as caught:
        parse_manifest(text, "m.yaml", base_dir=str(tmp_path))
    assert (caught.value.file, caught.value.entry, caught.value.line) == ("m.yaml", entry, line)
    assert f"Fix: keep one '{key}:'" in str(caught.value)


@pytest.mark.parametrize("text", ["", "# bags to convert\n\n# (none yet)\n"], ids=["0-bytes", "comments"])
def test_an_empty_manifest_says_it_has_no_bags_list(tmp_path: Path, text: str) -> None:
    manifest = tmp_path / "m.yaml"
    manifest.write_text(text)
    with pytest.raises(ManifestError, match=r"m\.yaml: has no 'bags:' list: the file is empty") as caught:
        load_manifest(str(manifest))
    assert caught.value.line is None and "line None" not in str(caught.value)
    assert "Fix: write 'bags:' then one '- uri: path/to/bag' line per bag" in str(caught.value)


@pytest.mark.parametrize(
    ("entry", "said", "fix"),
    [
        (
            "start_s: -1",
            "start_s: Input should be greater than or equal to 0",
            "start_s and end_s are seconds from the bag's first message",
        ),
        (
            "end_ns: later",
            "end_ns: Input should be a valid integer",
            "start_ns and end_ns are ROS times in integer nanoseconds",
        ),
        (
            "task: [a, b]",
            "task: Input should be a valid string",
            "task is the episode's task prompt, a string.",
        ),
    ],
)
def test_a_bad_value_of_an_entry_says_what_its_field_holds(entry: str, said: str, fix: str) -> None:
    with pytest.raises(ManifestError) as caught:
        parse_manifest(f"bags:\n  - uri: a.mcap\n    {entry}\n", "m.yaml")
    assert str(caught.value).startswith(f"m.yaml, bags[0]: line 3: {said}"), str(caught.value)
    assert f"Fix: {fix}" in str(caught.value)
    with pytest.raises(
        ManifestError, match=r"did you mean 'start_s'\? *$"
    ):  # a misspelt key keeps its advice
        parse_manifest("bags:\n  - uri: a.mcap\n    strat_s: 1\n", "m.yaml")
