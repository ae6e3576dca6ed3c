"""The HTML QA report: self-contained, and it renders in headless Chromium."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from bagport.episode import EpisodeRequest, convert_episode
from bagport.qa import EpisodeQA, QAConfig, QAEntry
from bagport.qa.report import render_report
from bagport.synth import EpisodeSpec, Faults, Window, write_episode_bag
from tests.helpers import FAST_SETTINGS, SAMPLE_CONTRACT, SMALL_CAMERAS


def _entries(tmp_path: Path) -> list[QAEntry]:
    entries = []
    faults = (Faults(), Faults(camera_dropout=Window(1.0, 0.4, "front"), joint_nan_at_s=2.0))
    for index, fault in enumerate(faults):
        bag = tmp_path / f"ep{index}"
        write_episode_bag(
            bag, "mcap", EpisodeSpec(duration_s=3.0, cameras=SMALL_CAMERAS, faults=fault, mcap_crcs=True)
        )
        request = EpisodeRequest(
            episode_id=f"ep{index}",
            bag_uri=str(bag),
            manifest_entry=index,
            staging_uri=str(tmp_path / "staging"),
            contract_text=SAMPLE_CONTRACT.read_text(),
            contract_name="sample_robot.yaml",
            encoder=FAST_SETTINGS,
            # the second episode asks for a PSNR no lossy clip reaches, so its worst frame is shown
            qa=QAConfig.model_validate(
                {"video": {"psnr_min_db": {"warn": 99.0, "fail": None}, "sample_every": 1}} if index else {}
            ),
        )
        summary = convert_episode(request)
        qa = EpisodeQA.from_dict(json.loads((Path(summary.dir_uri) / "qa.json").read_text()))
        entries.append(QAEntry(qa, index, index if qa.verdict != "fail" else None, None))
    entries.append(
        QAEntry(EpisodeQA.failed("s3://fleet/broken.mcap", "broken.mcap: not a bag"), 2, None, "failed")
    )
    return entries


@pytest.fixture(scope="module")
def report_html(tmp_path_factory: pytest.TempPathFactory) -> Path:
    tmp_path = tmp_path_factory.mktemp("report")
    html = render_report(_entries(tmp_path), {"episodes": 1, "frames": 90})
    path = tmp_path / "report.html"
    path.write_text(html, encoding="utf-8")
    return path


def test_report_is_self_contained_and_lists_every_episode(report_html: Path) -> None:
    html = report_html.read_text()
    assert not re.search(r"<script|<link|src=\"http|href=\"http", html)
    assert html.count("<details id=") == 3
    assert "values.non_finite" in html
    assert "rates.gap_periods" in html
    assert "broken.mcap: not a bag" in html
    assert html.count("<svg") >= 8  # rates, alignment histograms, traces, brightness per episode
    assert "messages per second, by topic" in html
    assert html.count("frames in clip / encoded") == 2  # video fidelity per converted episode
    assert html.count('alt="worst frame of') == 2  # both cameras of the warned episode
    assert html.count('class="strip"') == 2  # a thumbnail strip per camera, only for the warned episode
    assert html.count('<figure class="thumb">') == 16
    assert "damaged blocks outlined in red" in html


def test_report_renders_in_headless_chromium(report_html: Path, tmp_path: Path) -> None:
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "headless Chromium is needed (`make test` installs Debian's chromium)"
    screenshot = tmp_path / "report.png"
    subprocess.run(
        [chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars", "--window-size=1200,1600",
         f"--screenshot={screenshot}", report_html.as_uri()],
        check=True, capture_output=True, timeout=120,
    )  # fmt: skip
    image = np.asarray(Image.open(screenshot).convert("RGB"))
    assert image.shape[:2] == (1600, 1200)
    # Not a blank page: verdict colours and plot lines are there.
    colours = {tuple(c) for c in image.reshape(-1, 3)[::7].tolist()}
    assert len(colours) > 50
    red = (image[..., 0] > 180) & (image[..., 1] < 80) & (image[..., 2] < 80)
    assert red.sum() > 20  # the failing verdicts
