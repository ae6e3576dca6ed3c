"""Publishing datasets on the Hugging Face Hub (``bagport push``, ``convert --push-to-hub``)."""

from __future__ import annotations

from bagport.hub.push import PushReport, push_dataset
from bagport.hub.redact import PROVENANCE_CHOICES, ProvenanceChoice

__all__ = ["PROVENANCE_CHOICES", "ProvenanceChoice", "PushReport", "push_dataset"]
