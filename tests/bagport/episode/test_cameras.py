"""Every image encoding through the whole pipeline: synthetic bag -> convert -> LeRobot -> true pixels.

Colour cameras are compared with the frame the bag holds at each tick (the codec here is H.264
yuv444p crf 0: only the RGB <-> YUV rounding is lost). Depth cameras are compared with the depth a
ROS subscriber decodes from the bag, within half a 12-bit code of LeRobot's log quantisation.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np
import numpy.typing as npt
import pytest
import simplejpeg
import yaml

from bagport.contract import parse_contract
from bagport.dataset import write_dataset
from bagport.dataset.validate import validate_dataset, video_backend
from bagport.episode import EpisodeRequest, convert_episode, episode_id_for
from bagport.errors import ContractError, DecodeError
from bagport.feature_table import describe_features
from bagport.qa import EpisodeQA
from bagport.staging import QA_FILE, EpisodeSummary
from bagport.synth import CameraSpec, EpisodeSpec, GroundTruth, render_frame, write_episode_bag
from bagport.synth.images import depth_frame, recorded_depth
from bagport.video.depth import DepthQuantizer
from bagport.video.settings import EncoderSettings
from tests.helpers import episode_request

NS = 1_000_000_000
FPS = 30
H, W = 48, 64
LOSSLESS_ISH = EncoderSettings.from_dict(
    {"codec": "libx264", "pix_fmt": "yuv444p", "crf": 0, "preset": "ultrafast", "g": 2}
)
COLOUR = ["rgb8", "bgr8", "rgba8", "bgra8", "mono8", "8UC1", "8UC3", "mono16"]
BAYER = ["bayer_rggb8", "bayer_bggr8", "bayer_gbrg8", "bayer_grbg8"]
DEPTH = [("raw", "16UC1"), ("raw", "32FC1"), ("compressed_depth", "16UC1"), ("compressed_depth", "32FC1")]
RVL = "cdepth_rvl_16uc1"
"""A compressedDepth camera in compressed_depth_image_transport's RVL format."""
NEAR_RANGE_M = (0.2, 7.0)
"""``image.depth_range_m`` of the raw 16UC1 camera (the others keep LeRobot's 0.01-10 m)."""


def _name(encoding: str, kind: str = "raw") -> str:
    return f"{kind}_{encoding}".lower().replace("compressed_depth", "cdepth")


def _cameras() -> tuple[CameraSpec, ...]:
    cams = [CameraSpec(_name(e), "raw", e, height=H, width=W) for e in COLOUR + BAYER]
    cams += [CameraSpec(_name(k), k, height=H, width=W) for k in ("jpeg", "png")]
    cams += [CameraSpec(_name(e, k), k, e, height=H, width=W) for k, e in DEPTH]  # type: ignore[arg-type]
    cams.append(CameraSpec(RVL, "compressed_depth", "16UC1", height=H, width=W, depth_codec="rvl"))
    return tuple(cams)


def _contract(cameras: tuple[CameraSpec, ...]) -> str:
    observations: list[dict[str, Any]] = [
        {"key": "observation.state", "topic": "/joint_states", "type": "sensor_msgs/msg/JointState"}
    ]
    for cam in cameras:
        entry: dict[str, Any] = {
            "key": f"observation.images.{cam.name}",
            "topic": cam.topic,
            "type": cam.msgtype,
        }
        if cam.name == _name("16UC1"):
            entry["image"] = {"depth_range_m": list(NEAR_RANGE_M)}
        observations.append(entry)
    return yaml.safe_dump({"robot_type": "r", "fps": FPS, "observations": observations})


def _convert(tmp: Path, spec: EpisodeSpec, contract: str) -> EpisodeSummary:
    bag = tmp / "bag"
    write_episode_bag(bag, "mcap", spec)
    return convert_episode(
        EpisodeRequest(
            episode_id=episode_id_for(str(bag), contract, LOSSLESS_ISH),
            bag_uri=str(bag),
            manifest_entry=0,
            staging_uri=str(tmp / "staging"),
            contract_text=contract,
            contract_name="cameras.yaml",
            encoder=LOSSLESS_ISH,
        )
    )


@pytest.fixture(scope="module")
def converted(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, EpisodeSummary, GroundTruth]:
    tmp = tmp_path_factory.mktemp("cameras")
    spec = EpisodeSpec(duration_s=0.8, cameras=_cameras(), seed=5)
    summary = _convert(tmp, spec, _contract(spec.cameras))
    out = tmp / "ds"
    write_dataset([summary], str(out), robot_type="r")
    return out, summary, GroundTruth(spec)


def _flat(rgb: npt.NDArray[np.uint8]) -> npt.NDArray[np.bool_]:
    """Pixels whose 5x5 neighbourhood has one colour (demosaicing is exact there)."""
    padded = np.pad(rgb.astype(np.int16), ((2, 2), (2, 2), (0, 0)), mode="edge")
    flat = np.ones(rgb.shape[:2], dtype=np.bool_)
    for dy in range(5):
        for dx in range(5):
            flat &= (padded[dy : dy + H, dx : dx + W] == rgb).all(axis=2)
    return flat


def _expected_colour(cam: CameraSpec, index: int) -> npt.NDArray[np.uint8]:
    rgb = render_frame(H, W, index)
    if cam.kind == "jpeg":  # what the bag holds is the JPEG's decoded pixels
        return np.asarray(simplejpeg.decode_jpeg(simplejpeg.encode_jpeg(rgb, quality=90, colorspace="RGB")))
    if cam.encoding.lower() in ("mono8", "8uc1", "mono16"):
        return np.repeat(rgb.mean(axis=2, keepdims=True).astype(np.uint8), 3, axis=2)
    return rgb


@pytest.mark.slow
def test_every_encoding_loads_in_lerobot_with_its_true_values(
    converted: tuple[Path, EpisodeSummary, GroundTruth],
) -> None:
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    out, summary, truth = converted
    dataset = LeRobotDataset("test/cameras", root=out, video_backend=video_backend(), depth_output_unit="m")
    depth_names = [_name(e, k) for k, e in DEPTH] + [RVL]
    assert sorted(dataset.meta.depth_keys) == sorted(f"observation.images.{name}" for name in depth_names)
    worst_colour, worst_depth_codes = 0, 0.0
    for k in range(len(dataset)):
        item = dataset[k]
        tick = summary.first_tick_ns + k * NS // FPS
        for cam in truth.spec.cameras:
            stamps = truth.camera_stamps_ns(cam.name)
            index = int(np.searchsorted(stamps, tick, side="right") - 1)  # hold: the frame at or before
            value = item[f"observation.images.{cam.name}"]
            if cam.is_depth:
                quantizer = DepthQuantizer(*NEAR_RANGE_M) if cam.name == _name("16UC1") else DepthQuantizer()
                expected = recorded_depth(depth_frame(H, W, index), cam.encoding, cam.kind != "raw")
                got = value.numpy()
                assert got.shape == (1, H, W)
                got = got[0]
                invalid = ~np.isfinite(expected)
                assert invalid.any() and np.allclose(got[invalid], quantizer.depth_min_m, rtol=0, atol=1e-6)
                step = quantizer.step_m(expected[~invalid])
                error = np.abs(got[~invalid] - expected[~invalid])
                assert (error <= step / 2 + 1e-5).all(), cam.name
                worst_depth_codes = max(worst_depth_codes, float((error / step).max()))
                continue
            rgb = (value.permute(1, 2, 0).numpy() * 255).round().astype(np.int16)
            expected_rgb = _expected_colour(cam, index)
            where = _flat(render_frame(H, W, index)) if "bayer" in cam.encoding else np.ones((H, W), np.bool_)
            diff = int(np.abs(rgb - expected_rgb)[where].max())
            assert diff <= 3, f"{cam.name} frame {k}: {diff} levels off"
            worst_colour = max(worst_colour, diff)
    print(f"worst colour error {worst_colour} levels; worst depth error {worst_depth_codes:.3f} codes")


@pytest.mark.slow
def test_depth_features_are_marked_and_their_stats_are_metres(
    converted: tuple[Path, EpisodeSummary, GroundTruth],
) -> None:
    out, summary, _ = converted
    info = json.loads((out / "meta/info.json").read_text())
    stats = json.loads((out / "meta/stats.json").read_text())
    near = info["features"][f"observation.images.{_name('16UC1')}"]
    assert near["shape"] == [H, W, 1] and near["dtype"] == "video"
    assert near["info"]["is_depth_map"] is True and near["info"]["depth_unit"] == "m"
    assert (near["info"]["video.depth_min"], near["info"]["video.depth_max"]) == NEAR_RANGE_M
    assert (near["info"]["video.codec"], near["info"]["video.pix_fmt"], near["info"]["video.channels"]) == (
        "hevc",
        "gray12le",
        1,
    )
    colour = info["features"][f"observation.images.{_name('rgb8')}"]
    assert colour["shape"] == [H, W, 3] and colour["info"]["is_depth_map"] is False
    key = f"observation.images.{_name('32FC1', 'compressed_depth')}"
    assert np.asarray(stats[key]["mean"]).shape == (1, 1, 1)
    # the ramp spans 0.3-6.5 m, a sixteenth of each frame is invalid (read back as depth_min)
    assert stats[key]["min"] == [[[pytest.approx(0.01, abs=1e-6)]]]
    assert 5.5 < stats[key]["max"][0][0][0] < 6.6 and 2.0 < stats[key]["mean"][0][0][0] < 4.0
    # LeRobot's default unit is millimetres: it rescales depth stats (and frames) from info's depth_unit
    from lerobot.datasets.lerobot_dataset import LeRobotDataset  # noqa: PLC0415 - heavy

    in_mm = LeRobotDataset("test/cameras", root=out, video_backend=video_backend())
    mean_mm = float(np.asarray(in_mm.meta.stats[key]["mean"]).ravel()[0])
    assert mean_mm == pytest.approx(stats[key]["mean"][0][0][0] * 1000, rel=1e-6)
    frame_mm = in_mm[0][key].numpy()
    in_m = LeRobotDataset("test/cameras", root=out, video_backend=video_backend(), depth_output_unit="m")
    np.testing.assert_allclose(frame_mm, np.rint(in_m[0][key].numpy() * 1000), atol=0.5)
    # QA: each depth clip was decoded again and matched its codes exactly
    qa = EpisodeQA.from_dict(json.loads(Path(summary.file(QA_FILE)).read_text()))
    depth_checks = [
        c for c in qa.checks if c.check.startswith("video.") and c.subject in in_m.meta.depth_keys
    ]
    assert sorted({c.check for c in depth_checks}) == ["video.damaged_frames", "video.frame_mismatch"]
    assert len(depth_checks) == 2 * (len(DEPTH) + 1) and all(c.verdict == "pass" for c in depth_checks), (
        depth_checks
    )
    assert qa.plots["fidelity"][key]["sampled_frames"] == summary.frames  # every depth frame checked
    assert validate_dataset(out, repo_id="test/cameras").frames_decoded == summary.frames


def test_a_colour_topic_with_depth_options_is_refused(tmp_path: Path) -> None:
    cam = CameraSpec("front", "raw", "rgb8", height=H, width=W)
    contract = yaml.safe_dump(
        {
            "robot_type": "r",
            "fps": FPS,
            "observations": [
                {
                    "key": "observation.images.front",
                    "topic": cam.topic,
                    "type": cam.msgtype,
                    "image": {"depth_range_m": [0.1, 2.0]},
                }
            ],
        }
    )
    with pytest.raises(DecodeError, match="depth_range_m is set but /front/image_raw carries colour images"):
        _convert(tmp_path, EpisodeSpec(duration_s=0.3, cameras=(cam,)), contract)


@pytest.mark.slow
def test_depth_stats_merge_exactly_when_appending(tmp_path: Path) -> None:
    cams = (CameraSpec("depth", "raw", "32FC1", height=16, width=24),)
    summaries = []
    for seed, duration_s in ((1, 0.3), (2, 0.5)):
        spec = EpisodeSpec(
            duration_s=duration_s, cameras=cams, seed=seed, start_ns=1_700_000_000 * NS + seed * NS
        )
        summaries.append(_convert(tmp_path / f"ep{seed}", spec, _contract(cams)))
    write_dataset(summaries[:1], str(tmp_path / "appended"), robot_type="r")
    write_dataset(summaries[1:], str(tmp_path / "appended"), robot_type="r", append=True)
    write_dataset(summaries, str(tmp_path / "at_once"), robot_type="r")
    key = f"observation.images.{cams[0].name}"
    appended = json.loads((tmp_path / "appended/meta/stats.json").read_text())[key]
    at_once = json.loads((tmp_path / "at_once/meta/stats.json").read_text())[key]
    assert appended["count"] == at_once["count"] == [sum(s.frames for s in summaries)]
    for stat in ("min", "max", "q01", "q50", "q99"):
        assert appended[stat] == at_once[stat]
    assert appended["mean"][0][0][0] == pytest.approx(at_once["mean"][0][0][0], rel=1e-12)
    assert 0.3 < at_once["q50"][0][0][0] < 6.5


def test_contract_check_shows_depth_cameras_with_one_channel(
    converted: tuple[Path, EpisodeSummary, GroundTruth],
) -> None:
    _, summary, truth = converted
    rows = {
        r.key: r for r in describe_features(parse_contract(_contract(truth.spec.cameras)), summary.bag_uri)
    }
    assert rows[f"observation.images.{_name('32FC1', 'compressed_depth')}"].shape == (H, W, 1)
    assert rows[f"observation.images.{_name('bayer_rggb8')}"].shape == (H, W, 3)


def test_an_empty_depth_range_is_a_contract_error() -> None:
    cam = CameraSpec("depth", "raw", "16UC1")
    bad = yaml.safe_load(_contract((cam,)))
    bad["observations"][1]["image"] = {"depth_range_m": [3.0, 1.0]}
    with pytest.raises(ContractError, match=r"depth_range_m \[3.0, 1.0\] must be \[min, max\] metres"):
        parse_contract(yaml.safe_dump(bad), "c.yaml")


def test_a_camera_of_odd_sides_is_named_with_its_topic_and_entry(tmp_path: Path) -> None:
    """4:2:0 video needs even sides: the error names the camera's topic and contract entry, not the clip being
    written in the episode's scratch folder."""
    camera = CameraSpec("front", "raw", "bgr8", height=33, width=49)
    spec = EpisodeSpec(duration_s=0.3, cameras=(camera,), task="look")
    write_episode_bag(tmp_path / "bag", "mcap", spec)
    request = episode_request(tmp_path / "bag", tmp_path / "staging", _contract((camera,)))  # 4:2:0
    with pytest.raises(DecodeError) as caught:
        convert_episode(request)
    said = str(caught.value)
    assert "camera observation.images.front: 49x33 frames cannot be encoded as yuv420p" in said
    assert "(contract.yaml:6, observations[key=observation.images.front])" in said
    assert caught.value.topic == camera.topic
    assert ".mp4" not in said
    assert "with even numbers for this camera" in caught.value.fix
