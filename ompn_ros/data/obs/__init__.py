"""Observations assembled from several topics: one rule and one code for ``ompn_node`` and the bag reader.

* :mod:`.spec`: :class:`ObservationSpec` / :class:`FieldSpec` (validated, YAML/dict form).
* :mod:`.extract`: field extractors from raw CDR (JointState, Float32/64MultiArray, WrenchStamped,
  PoseStamped, Float32/64), :func:`observation_layout` (dimension and element names).
* :mod:`.assembler`: :class:`ObservationAssembler`, the rule (latest partner at or before the step,
  within a tolerance, else a counted :class:`Drop`).
* :mod:`.stream`: :func:`assemble_stream`, the same assembler over recorded messages.
"""

from ompn_ros.data.errors import ObservationSpecError

from .assembler import DROP_REASONS, AssemblerStats, Decided, Drop, DropReason, ObservationAssembler
from .extract import ExtractError, TopicExtractor, observation_layout
from .spec import FIELDS, FieldSpec, ObservationSpec, StampSource
from .stream import AssembledStream, assemble_stream

__all__ = [
    "DROP_REASONS", "FIELDS", "AssembledStream", "AssemblerStats", "Decided", "Drop", "DropReason",
    "ExtractError", "FieldSpec", "ObservationAssembler", "ObservationSpec", "ObservationSpecError",
    "StampSource", "TopicExtractor", "assemble_stream", "observation_layout",
]
