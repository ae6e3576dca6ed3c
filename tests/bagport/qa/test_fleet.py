"""The fleet QA report in real Chromium (Playwright driving Debian's chromium): it loads with no script
error, filters by verdict, check, run and text, sorts by a column, and a failed episode's detail page
shows its checks, joint-named plots and camera thumbnails; after an append the main page covers both
runs."""

from __future__ import annotations

import json
import re
import shutil
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq
import pytest
from playwright.sync_api import Browser, Page, sync_playwright

from bagport.dataset.qa import QA_INDEX_PATH, write_qa
from bagport.episode import EpisodeRequest, convert_episode
from bagport.qa import EpisodeQA, QAEntry
from bagport.qa.fleet import index_table, render_fleet_page
from bagport.synth import EpisodeSpec, Faults, Window, write_episode_bag
from bagport.synth.qa_entries import synth_qa_entries
from tests.helpers import FAST_SETTINGS, SAMPLE_CONTRACT, SMALL_CAMERAS

pytestmark = pytest.mark.slow

NAMES = {
    "observation.state": ("j1", "j2", "j3", "j4", "j5", "j6"),
    "action": ("j1", "j2", "j3", "j4", "j5", "j6"),
}


def _converted(tmp_path: Path) -> list[QAEntry]:
    """A clean episode and one with NaN joints and a camera dropout (a hard failure, excluded)."""
    entries = []
    for index, fault in enumerate(
        (Faults(), Faults(camera_dropout=Window(1.0, 0.4, "front"), joint_nan_at_s=2.0))
    ):
        bag = tmp_path / "fleet" / f"nan-{index}"
        write_episode_bag(
            bag, "mcap", EpisodeSpec(duration_s=3.0, cameras=SMALL_CAMERAS, faults=fault, mcap_crcs=True)
        )
        request = EpisodeRequest(
            episode_id=f"ep{index}", bag_uri=str(bag), manifest_entry=index, staging_uri=str(tmp_path / "staging"),
            contract_text=SAMPLE_CONTRACT.read_text(), contract_name="sample_robot.yaml", encoder=FAST_SETTINGS,
        )  # fmt: skip
        summary = convert_episode(request)
        qa = EpisodeQA.from_dict(json.loads((Path(summary.dir_uri) / "qa.json").read_text()))
        entries.append(QAEntry(qa, index, 0 if qa.verdict != "fail" else None, None))
    assert [e.qa.verdict for e in entries] == ["pass", "fail"]
    return entries


@pytest.fixture(scope="module")
def report(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp_path = tmp_path_factory.mktemp("fleet")
    root = tmp_path / "ds"
    first = _converted(tmp_path) + synth_qa_entries(200, seed=1)
    write_qa(root, first, {"episodes": 2, "fps": 30}, {}, 0, robot_type="arm", names=NAMES)
    write_qa(root, synth_qa_entries(50, seed=2), {"episodes": 3, "fps": 30}, {}, 1, robot_type="arm")
    return root / "meta/qa/report.html"


@pytest.fixture(scope="module")
def browser() -> Iterator[Browser]:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "headless Chromium is needed (`make test` installs Debian's chromium)"
    with sync_playwright() as playwright:
        launched = playwright.chromium.launch(
            executable_path=chromium, args=["--no-sandbox", "--disable-gpu"]
        )
        yield launched
        launched.close()


@pytest.fixture
def page(browser: Browser, report: Path) -> Iterator[Page]:
    page = browser.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda err: errors.append(str(err)))
    page.on("requestfailed", lambda request: errors.append(request.url))
    page.goto(report.as_uri())
    yield page
    assert not errors, errors  # no script error, nothing fetched that is not there
    page.close()


def _rows(page: Page) -> list[dict[str, str]]:
    result: list[dict[str, str]] = page.eval_on_selector_all(
        "#ep-body tr",
        "rows => rows.map(r => ({verdict: r.dataset.verdict, run: r.cells[0].textContent, "
        "bag: r.cells[2].textContent, score: r.cells[3].textContent, checks: r.cells[5].textContent}))",
    )
    return result


def _index(report: Path) -> list[dict[str, object]]:
    root = report.parents[2]
    return [row for run in (0, 1) for row in pq.read_table(root / QA_INDEX_PATH.format(run=run)).to_pylist()]


def test_the_main_page_loads_and_covers_every_run(page: Page, report: Path) -> None:
    index = _index(report)
    assert len(index) == 252
    assert page.text_content("#ep-count") == f"1-100 of {len(index)} episode(s)"
    assert "over 2 run(s)" in (page.text_content("body") or "")
    assert page.locator("h3", has_text="By robot type").count() == 1
    assert page.locator("h3", has_text="By bag folder").count() == 1
    assert page.locator("h3", has_text="By day").count() == 1
    worst = page.locator("h2:has-text('20 worst episodes') + table tr")
    assert worst.count() == 21  # header + 20
    assert report.stat().st_size < 2 * 1024 * 1024 * 252 / 10_000  # on course for <= 2 MB at 10,000
    page.select_option("#f-run", "1")
    rows = _rows(page)
    assert len(rows) == 50 and {r["run"] for r in rows} == {"1"}


def test_filters_by_verdict_check_and_text(page: Page, report: Path) -> None:
    index = _index(report)
    page.select_option("#f-verdict", "fail")
    rows = _rows(page)
    assert len(rows) == sum(r["verdict"] == "fail" for r in index) > 0
    assert {r["verdict"] for r in rows} == {"fail"}
    page.select_option("#f-verdict", "")
    page.select_option("#f-check", label="values.non_finite")
    rows = _rows(page)
    expected = [r for r in index if "values.non_finite" in [*r["fails"], *r["warns"]]]  # type: ignore[misc]
    assert len(rows) == len(expected) > 0
    assert all("values.non_finite" in r["checks"] for r in rows)
    page.select_option("#f-check", "")
    page.fill("#f-text", "nan-1")
    rows = _rows(page)
    assert [r["bag"] for r in rows] == ["nan-1"]


def test_sorts_by_score_both_ways(page: Page) -> None:
    page.click("th[data-col='3']")  # score is the default sort: a click turns it to descending
    scores = [float(r["score"]) for r in _rows(page)]
    assert scores == sorted(scores, reverse=True) and scores[0] == 1.0
    page.click("th[data-col='3']")
    scores = [float(r["score"]) for r in _rows(page)]
    assert scores == sorted(scores) and scores[0] < 0.4
    assert page.get_attribute("th[data-col='3']", "class") == "sorted-asc"


def test_a_failed_episode_opens_its_detail(page: Page) -> None:
    page.fill("#f-text", "nan-1")
    page.click("#ep-body a")
    page.wait_for_load_state()
    assert re.search(r"details/run-000/000001\.html$", page.url)
    body = page.text_content("body") or ""
    assert "values.non_finite" in body and "NaN" in body
    assert "rates.gap_periods" in body  # the camera dropout
    legend = page.locator(".legend").all_text_contents()
    assert any("j1" in text and "j6" in text for text in legend)  # joints by name
    assert any("observation.images.front" in text for text in legend)  # cameras by full key
    strips = page.locator(".strip h4").all_text_contents()
    assert strips == ["observation.images.front", "observation.images.wrist"]
    loaded = page.eval_on_selector_all(
        ".strip img", "imgs => imgs.filter(i => i.complete && i.naturalWidth > 0).length"
    )
    assert loaded >= 10  # the thumbnails decode
    assert page.locator("svg").count() >= 5
    page.click("text=QA report")
    assert page.url.endswith("meta/qa/report.html")


def test_passing_episodes_have_no_detail_page(report: Path) -> None:
    details = report.parent / "details"
    index = _index(report)
    assert len(list(details.rglob("*.html"))) == sum(r["verdict"] != "pass" for r in index)


def test_a_long_reason_is_cut_with_an_ellipsis_and_a_short_one_is_whole() -> None:
    """The worst-episodes table (200 characters) and the episode table's data (90) cut a long reason
    visibly: the whole one is on the episode's detail page."""
    entries = [e for e in synth_qa_entries(40, seed=3) if e.qa.verdict != "pass"][:2]
    long_reason = "excluded by QA: " + " ".join(f"check{n} failed" for n in range(60))
    entries[0] = replace(entries[0], excluded_reason=long_reason, episode_index=None)
    entries[1] = replace(entries[1], excluded_reason="short reason", episode_index=None)
    html = render_fleet_page(index_table(entries, 0, "arm"), {"episodes": 2}, 0)
    assert long_reason not in html and "short reason" in html
    worst = re.search(r"worst episodes</h2>(.*?)</table>", html, re.S)
    assert worst is not None and long_reason[:150] in worst.group(1) and "\u2026</td>" in worst.group(1)
    data = re.search(r"id='qa-data'>(.*?)</script>", html, re.S)
    assert data is not None
    payload = json.loads(data.group(1).replace("<\\/", "</"))
    reasons = sorted(row[-1] for row in payload["rows"])
    assert reasons[0].endswith("\u2026") and len(reasons[0]) == 90 and reasons[1] == "short reason"
