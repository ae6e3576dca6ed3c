"""Per-episode conversion: one bag in, one staged artifact out."""

from __future__ import annotations

from bagport.episode.convert import convert_episode
from bagport.request import EpisodeRequest, episode_id_for

__all__ = ["EpisodeRequest", "convert_episode", "episode_id_for"]
