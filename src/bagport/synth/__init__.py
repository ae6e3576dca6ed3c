"""Synthetic bags with known ground truth, for tests, demos and benchmarks."""

from __future__ import annotations

from bagport.synth.faults import Faults, Window
from bagport.synth.pixels import bar_means, decode_frame_index, expected_bar_colours, render_frame
from bagport.synth.spec import CameraSpec, EpisodeSpec
from bagport.synth.split import split_recording
from bagport.synth.truth import GroundTruth
from bagport.synth.write import SynthStorage, write_episode_bag, write_sample_fleet

__all__ = [
    "CameraSpec",
    "EpisodeSpec",
    "Faults",
    "GroundTruth",
    "SynthStorage",
    "Window",
    "bar_means",
    "decode_frame_index",
    "expected_bar_colours",
    "render_frame",
    "split_recording",
    "write_episode_bag",
    "write_sample_fleet",
]
